"""The Station: one vehicle's live core and the one way in for the server and the CLI.

It owns every piece of loop-side state (link, vehicle, streams, parameters, forwarding outputs,
estimation, recording, tuning) and runs each part under a `Supervisor`. Readers get typed
`StationSnapshot`s published at a fixed rate; writers call its commands, which must run on the
event loop thread (a route handler is `async def`; anything else hops in with
`loop.call_soon_threadsafe`). Heavy work (replay, what-if, export) runs in a worker process.
Data flow and conventions: docs/design.md
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
import multiprocessing
import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ParamSpec, TypeVar

import numpy as np

from gcs.core.declination import DECLINATION_PARAMS
from gcs.core.estimation import AttitudePoint, EstimationPipeline, pipeline_from
from gcs.core.estimators.base import AttitudeEstimator
from gcs.core.gains import GainSet, PresetFile
from gcs.mavlink.ascii import SEED000, AsciiFormat
from gcs.mavlink.signing import Signing
from gcs.runtime.bus import MessageBus
from gcs.runtime.estimation import LiveEstimation
from gcs.runtime.events import EventLog
from gcs.runtime.firmware import request_version
from gcs.runtime.forward import Output
from gcs.runtime.link import Link, LinkEvent
from gcs.runtime.logdownload import LogDownloader, LogDownloadError
from gcs.runtime.params import ParamClient
from gcs.runtime.protocol import LiveProtocol
from gcs.runtime.radio import RadioGovernor
from gcs.runtime.recorder import SessionRecorder
from gcs.runtime.signal import Signal
from gcs.runtime.snapshots import RadioSnapshot, RecordingSnapshot, StationSnapshot, StreamsSnapshot
from gcs.runtime.streams import StreamPlan, StreamRequester
from gcs.runtime.supervisor import PartStatus, Supervisor
from gcs.runtime.tuning import TuningSession, open_session
from gcs.runtime.vehicle import VehicleState
from gcs.runtime.vehicle_link import VehicleLink
from gcs.sessions.protocol import load_protocol
from gcs.sessions.workbench import warm_up

#: Seconds between published snapshots (and comparison rows in a recording).
SNAPSHOT_INTERVAL = 1.0

#: ArduPilot sets COMPASS_DEC when it sets its home, which can be seconds after the first 3D fix the
#: station sees, and does not send the new value: from that fix the station asks every
#: DECLINATION_RETRY s until the vehicle has given a non-zero one, at most DECLINATION_ASKS times.
DECLINATION_RETRY = 5.0
DECLINATION_ASKS = 12

#: How much lower the worker process's priority is than the station's (Unix nice increment).
WORKER_NICE = 10

NOT_RECORDING = RecordingSnapshot("off", None, None, 0, None, 0, 0, 0, None)

P = ParamSpec("P")
R = TypeVar("R")


@dataclass
class StationConfig:
    connect: str
    baud: int | str = 57600
    speed: float = 1.0
    outputs: list[str] = field(default_factory=list)
    heartbeat_timeout: float = 3.0
    plan: StreamPlan = field(default_factory=StreamPlan)
    request_streams: bool = True
    estimate: bool = True
    #: the sessions folder (--record-dir): recorded into when `record`, and what the sessions,
    #: replay and what-if lists read either way (one owner: a second field for the lists of a
    #: station that does not record could only ever repeat it)
    sessions_dir: str = "sessions"
    record: bool = False  # record every session (the commands' default; --no-record)
    ascii_format: AsciiFormat = SEED000  # the text lines of an ascii: link
    presets: list[PresetFile] = field(default_factory=list)  # estimators start from these (--preset-file)
    signing_key: bytes | None = None  # MAVLink 2 signing key (--signing-key); None: no signing
    signing_required: bool = True  # refuse unsigned packets (else accept and count them)


class StationError(Exception):
    """A command that cannot be carried out as asked; the message says why."""


class Station:
    """`link`: a vehicle's view of a link the fleet owns (gcs.runtime.fleet); without it the
    station opens `config.connect` itself and serves the first vehicle heard there."""

    def __init__(
        self,
        config: StationConfig,
        bus: MessageBus | None = None,
        *,
        link: VehicleLink | None = None,
        outputs: list[Output] | None = None,
    ) -> None:
        self.config = config
        self.events = EventLog()
        self.supervisor = Supervisor(self.events)
        self._owns_link = link is None
        if link is not None:
            self.bus = link.bus
            self.link: Link = link
        else:
            self.bus = bus or MessageBus()
            self.link = Link(
                config.connect,
                bus=self.bus,
                baud=config.baud,
                speed=config.speed,
                heartbeat_timeout=config.heartbeat_timeout,
                ascii_format=config.ascii_format,
                signing=signing_of(config),
            )
        self.vehicle = VehicleState(self.link, events=self.events)
        self.streams = StreamRequester(self.link, config.plan)
        self.vehicle.rebooted.connect(self.streams.request_again)
        #: the telemetry radio's budget: caps the requested rates when a radio reports (gcs.runtime.radio)
        self.radio = RadioGovernor(
            self.link, self.streams, self.events, config.baud if isinstance(config.baud, int) else 57600
        )
        self.streams.rate_cap = self.radio.cap
        self.params = ParamClient(self.link, self.vehicle, self.events)
        #: forwarding outputs: the station's own, or (with a fleet's link) the fleet's, shown here
        self.outputs = outputs if outputs is not None else [Output(address, [self.link]) for address in config.outputs]
        self.estimation = LiveEstimation(self.link, pipeline_from(config.presets)) if config.estimate else None
        self.link.state_changed.connect(self._link_state_changed)
        self.link.noted.connect(self._link_noted)
        if self.estimation is not None:  # the magnetometer's declination comes from the vehicle:
            # asked at connect, after the first 3D fix (ArduPilot sets COMPASS_DEC only then, and
            # does not say so) and after a reboot; every change is recorded in the event log
            #: the estimation saw a first 3D fix: the declination part asks until the vehicle gives it
            self._gps_locked = asyncio.Event()
            self.link.state_changed.connect(self._ask_declination)
            self.estimation.gps_locked.connect(self._gps_locked.set)
            self.vehicle.rebooted.connect(self._request_declination)
            self.estimation.declination_changed.connect(self._declination_changed)
        #: every snapshot as it is published
        self.published: Signal[[StationSnapshot]] = Signal()
        #: the attitudes the live estimation produces, as it produces them
        self.points: Signal[[list[AttitudePoint]]] = Signal()
        if self.estimation is not None:
            self.estimation.points.connect(self.points.emit)
        replaying = self.link.address.kind == "tlog"  # a replayed log is not a new session
        self.recorder = SessionRecorder(self, config.sessions_dir) if config.record and not replaying else None
        #: the test protocol being run (or the last one), see gcs.runtime.protocol
        self.protocol: LiveProtocol | None = None
        self._tuning: TuningSession | None = None
        self._tuning_lock: asyncio.Lock | None = None
        self._download: asyncio.Task[Any] | None = None
        #: the vehicle's onboard logs (gcs.runtime.logdownload); downloads land in the replay folder
        self.onboard_logs = LogDownloader(self.link)
        self._log_download: asyncio.Task[Any] | None = None
        self._snapshot: StationSnapshot | None = None
        self._loop_thread: int | None = None
        self._workers: ProcessPoolExecutor | None = None
        self.supervisor.changed.connect(self._part_changed)

    # ---- lifecycle ---------------------------------------------------------------------
    async def start(self) -> None:
        """Start every part under the supervisor (the recorder first, so it has the first byte)."""
        self.launch()

    def launch(self) -> None:
        """`start` without waiting: every part is a task once this returns (the fleet starts a
        vehicle's core this way, then hands it the heartbeat that revealed the vehicle)."""
        self._loop_thread = threading.get_ident()
        if self.recorder is not None:
            self.recorder.start()
        if self.estimation is not None:
            self.estimation.subscribe()  # sees what the recorder sees, from the same message on
        run = self.supervisor.start
        if self._owns_link:  # first: a replayed .tlog's link waits for them
            for i, output in enumerate(self.outputs):
                run(f"output {i + 1}", output.run())
        run("link", self.link.run())
        run("vehicle", self.vehicle.run())
        run("params", self.params.run())
        # not for a parameter-only command, nor for an ascii: link's text lines (no MAVLink reaches
        # them), nor for a replayed .tlog (a file is no vehicle: nothing is sent to it, Link.send_raw)
        address = self.link.address
        negotiates = self.config.request_streams and address.framing != "ascii" and address.kind != "tlog"
        if negotiates:  # ask the firmware version, and the streams
            run("firmware", request_version(self.link, lambda: self.vehicle.firmware is not None))
            run("streams", self.streams.run())
            run("radio", self.radio.run())
        if self.estimation is not None:
            run("estimation", self.estimation.run())
            run("declination", self._ask_declination_until_given())
        if self.recorder is not None:
            run("recorder", self.recorder.run())
        run("snapshots", self._publish_loop())

    async def stop(self) -> None:
        if self.protocol is not None:
            self.protocol.finish()
        await self.supervisor.stop(first="link")  # nothing arrives while the others finish
        if self.recorder is not None:
            self.recorder.close()
        if self._workers is not None:
            workers, self._workers = self._workers, None
            # joined, off the loop: a pool left shutting down (wait=False) raced CPython 3.11's exit
            # hook, which then wrote to the pool's closed wakeup pipe ("Bad file descriptor" printed
            # at the process's exit, once in 24 CI runs)
            await asyncio.to_thread(workers.shutdown, wait=True, cancel_futures=True)

    async def link_finished(self) -> None:
        """Returns when the link has ended by itself (a replayed log reached its end)."""
        await self.supervisor.task("link")

    def _link_state_changed(self, old: str, new: str) -> None:
        """Each state change in the event log; a loss with its reason (`Link.lost_reason`), so the
        session says whether the cable, the peer or the radio went."""
        why = {"reason": self.link.lost_reason} if new == "lost" and self.link.lost_reason else {}
        self.events.record("link", "link", old=old, new=new, **why)

    def _link_noted(self, event: LinkEvent) -> None:
        """The transport's events go to the event log (and the session's events.jsonl) too: a serial
        port that vanished mid-flight ("closed /dev/ttyUSB0: the device is gone (Input/output
        error)") was otherwise told only by `gcs status`; the session and `gcs serve` showed a link
        lost as a radio fade is, 3 s later."""
        if event.kind in ("transport", "baud"):
            self.events.record("link", "link", text=event.detail)

    def follow_system(self, sysid: int) -> None:
        """Estimate from this system's data only (a fleet's core: its vehicle's), not from the
        first system that sends IMU data."""
        if self.estimation is not None:
            self.estimation.inputs.sampler.system = sysid

    # ---- snapshots ---------------------------------------------------------------------
    @property
    def snapshot(self) -> StationSnapshot:
        """The latest published snapshot (published now if there is none yet)."""
        return self._snapshot if self._snapshot is not None else self.publish()

    def publish(self) -> StationSnapshot:
        """Take a snapshot of every part now and hand it to the listeners."""
        streams, radio = self.streams.snapshot(), self.radio.snapshot()
        estimation = self.estimation
        self._snapshot = StationSnapshot(
            published=time.time(),
            link=self.link.snapshot(),
            vehicle=self.vehicle.snapshot(),
            streams=streams,
            outputs=[o.snapshot() for o in self.outputs],
            estimation=None
            if estimation is None
            else estimation.snapshot(time.monotonic(), imu_rate_limit(estimation.imu_type, streams, radio)),
            recording=self.recording_snapshot(),
            parts=self.supervisor.statuses(),
            radio=radio,
        )
        self.published.emit(self._snapshot)
        return self._snapshot

    async def _publish_loop(self) -> None:
        while True:
            await asyncio.sleep(SNAPSHOT_INTERVAL)
            self.publish()

    def _part_changed(self, status: PartStatus) -> None:
        if self._snapshot is not None:  # a failure shows at once, not at the next tick
            self._snapshot = dataclasses.replace(self._snapshot, parts=self.supervisor.statuses())

    def latest_attitudes(self) -> tuple[dict[str, AttitudePoint], dict[str, np.ndarray]]:
        """Latest attitude per source and the estimators' quaternions, for the pose view."""
        self._on_loop()
        if self.estimation is None:
            return {}, {}
        pipeline = self.estimation.pipeline
        return dict(pipeline.latest), {name: est.quaternion.copy() for name, est in pipeline.estimators.items()}

    # ---- commands: estimator gains -------------------------------------------------------
    def estimator(self, name: str) -> AttitudeEstimator:
        """The running estimator `name`; KeyError names the running ones."""
        pipeline = self._pipeline()
        if name not in pipeline.estimators:
            raise KeyError(f"unknown estimator {name!r}; running: {', '.join(pipeline.estimators)}")
        return pipeline.estimators[name]

    def estimator_names(self) -> list[str]:
        return [] if self.estimation is None else list(self.estimation.pipeline.estimators)

    def pace_points(self, interval: Callable[[], float]) -> None:
        """The live points are wanted at most every interval() s (the dashboard's frame interval):
        a UDP link is read that often (`Link.pace_reads`), and the estimation takes each read in
        one turn; on any other link it gathers what arrives within the interval into one turn
        (runtime.estimation.TICK)."""
        self.link.pace_reads(interval)
        if self.estimation is not None:
            self.estimation.pace(interval)

    def set_gain(self, estimator: str, gain: str, value: float, client: str) -> tuple[float, float]:
        """Apply one gain now and record the change (old, new, client); GainError for a bad
        value or name, KeyError for an unknown estimator."""
        self._on_loop()
        old, new = self._pipeline().set_gain(estimator, gain, value)
        if new != old:
            self.events.record("gain", client, estimator=estimator, gain=gain, old=old, new=new)
        return old, new

    def reset_gains(self, estimator: str, preset: str | None, client: str) -> dict[str, tuple[float, float]]:
        """Every gain to the preset's value (default: the estimator's own preset), except a
        declination the vehicle reported. Returns the changes {gain: (old, new)}."""
        est = self.estimator(estimator)
        preset = preset or est.DEFAULT_PRESET
        target = GainSet(est.gains.declarations.values(), est.gains.presets)
        target.apply_preset(preset)  # GainError names the known presets
        est.preset = preset  # before the gains' events: what shows them names the new preset
        changes = {}
        for name, value in target.values.items():
            if name == "declination" and self._pipeline().declination is not None:
                continue
            old, new = self.set_gain(estimator, name, value, client)
            if new != old:
                changes[name] = (old, new)
        self.events.record("preset", client, estimator=estimator, preset=preset)  # pages show the name
        return changes

    # ---- commands: recording -------------------------------------------------------------
    @property
    def recording_root(self) -> Path:
        """Where sessions are recorded (and where replay and what-if sources are looked up)."""
        return Path(self.config.sessions_dir)

    def recording_snapshot(self) -> RecordingSnapshot:
        """The recorder's state now (not at the last published snapshot)."""
        return self.recorder.snapshot() if self.recorder is not None else NOT_RECORDING

    def recording(self) -> SessionRecorder:
        if self.recorder is None:
            raise StationError("this station runs without recording (--no-record)")
        return self.recorder

    def start_recording(self) -> RecordingSnapshot:
        self._on_loop()
        recorder = self.recording()
        recorder.start_recording()
        return recorder.snapshot()

    async def stop_recording(self, client: str) -> RecordingSnapshot:
        """Detach the session on the loop, then close it (flush, Parquet) in a worker thread:
        disk work that must not hold the loop, on a session no live part touches any more."""
        self._on_loop()
        recorder = self.recording()
        session = recorder.detach(client)
        if session is not None:
            try:
                await asyncio.to_thread(recorder.finish, session)
            except OSError as exc:
                recorder.report_error(f"cannot close session {session.folder}: {exc.strerror or exc}")
        return recorder.snapshot()

    def add_note(self, text: str, client: str) -> None:
        """A note for the session being recorded; StationError when none is (it was answered
        "ok" and kept in no session)."""
        self._on_loop()
        if not self.recording().note(text, client):
            raise StationError("not recording: a note is kept in the session being recorded; start recording first")

    # ---- commands: test protocols -------------------------------------------------------------
    def start_protocol(self, name_or_path: str, detect_source: str | None, client: str) -> LiveProtocol:
        """Start a test protocol (a shipped name or a TOML file), ending any run in progress;
        ProtocolError names what is wrong with the file."""
        self._on_loop()
        protocol = load_protocol(name_or_path)
        self.stop_protocol()
        self.protocol = LiveProtocol(self, protocol, detect_source, client)
        return self.protocol

    def stop_protocol(self) -> None:
        """End the protocol run in progress, if any (its results stay readable)."""
        self._on_loop()
        if self.protocol is not None:
            self.protocol.finish()

    # ---- commands: vehicle parameters and tuning ---------------------------------------------
    def start_param_download(self) -> bool:
        """Start a full parameter download unless one runs; True if this call started it."""
        self._on_loop()
        if self._download is not None and not self._download.done():
            return False
        self._download = asyncio.get_running_loop().create_task(self.params.download())
        self._download.add_done_callback(lambda t: t.cancelled() or t.exception())  # the error stays in progress()
        return True

    def start_log_download(self, log_id: int | None) -> bool:
        """List the vehicle's logs and download `log_id` (None: the latest) into the recording
        folder, where replay finds it; False if a listing or download is already running."""
        self._on_loop()
        if self._log_download is not None and not self._log_download.done():
            return False

        async def fetch() -> None:
            entries = await self.onboard_logs.list_logs()
            chosen = [e for e in entries if log_id is None or e.id == log_id][-1:]
            if not chosen:
                raise LogDownloadError(f"the vehicle has no log {log_id}" if log_id else "the vehicle has no logs")
            path = await self.onboard_logs.download(chosen[0], self.recording_root)
            self.events.record("log download", "station", log=chosen[0].id, path=str(path))

        self._log_download = asyncio.get_running_loop().create_task(fetch())
        self._log_download.add_done_callback(self._log_download_done)
        return True

    def _log_download_done(self, task: asyncio.Task[Any]) -> None:
        error = None if task.cancelled() else task.exception()
        if error is not None:  # a refusal, a lost link, a full disk: shown in the progress
            self.onboard_logs.fail(str(error))

    async def tuning(self) -> TuningSession:
        """The tuning session (opened on first use: profile detected, pre-flight values snapshotted)."""
        self._on_loop()
        if self._tuning_lock is None:
            self._tuning_lock = asyncio.Lock()
        async with self._tuning_lock:
            if self._tuning is None:
                self._tuning = await open_session(self.params)
        return self._tuning

    def started_tuning(self) -> TuningSession | None:
        """The tuning session if something opened it (`tuning`), else None: reading it talks to
        nobody, where opening it reads the profile's parameters from the vehicle."""
        return self._tuning

    # ---- heavy work ------------------------------------------------------------------------
    async def in_worker(self, function: Callable[P, R], *args: P.args, **kwargs: P.kwargs) -> R:
        """Run function(*args) in the station's worker process: CPU-heavy work (replay, what-if,
        export, report) on its own copy of the data, so the live loop never waits on it. The
        worker keeps its decode caches between calls, and runs at a lower priority (nice
        WORKER_NICE) so that on a machine with few cores it yields the CPU to the live process."""
        if self._workers is None:
            # spawned, not forked: a fork would inherit the server's sockets and pipes (and threads)
            self._workers = ProcessPoolExecutor(
                max_workers=1,
                mp_context=multiprocessing.get_context("spawn"),
                initializer=_lower_priority,
                initargs=(WORKER_NICE,),
            )
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(self._workers, _call, function, args, kwargs)

    # ---- helpers -----------------------------------------------------------------------------
    def _ask_declination(self, old: str, new: str) -> None:
        if new == "connected":
            self._request_declination()

    def _request_declination(self) -> None:
        self.params.request(DECLINATION_PARAMS)

    async def _ask_declination_until_given(self) -> None:
        """From each first 3D fix (a reboot's too), ask every DECLINATION_RETRY s until the vehicle
        has given a non-zero value, at most DECLINATION_ASKS times."""
        assert self.estimation is not None
        declination = self.estimation.inputs.vehicle_declination
        while True:
            await self._gps_locked.wait()
            self._gps_locked.clear()
            for _ in range(DECLINATION_ASKS):
                if declination.vehicle is not None:
                    break
                self._request_declination()
                await asyncio.sleep(DECLINATION_RETRY)

    def _declination_changed(self, source: str, value: float | None) -> None:
        deg = None if value is None else round(math.degrees(value), 3)
        self.events.record("declination", "estimation", source=source, declination_rad=value, declination_deg=deg)

    def _pipeline(self) -> EstimationPipeline:
        if self.estimation is None:
            raise StationError("the station runs without estimation: no estimators")
        return self.estimation.pipeline

    def _on_loop(self) -> None:
        """Commands touch live state: only the event loop's thread may call them."""
        if self._loop_thread is not None and threading.get_ident() != self._loop_thread:
            raise RuntimeError("Station commands run on the event loop thread (use loop.call_soon_threadsafe)")


def imu_rate_limit(imu_type: str | None, streams: StreamsSnapshot, radio: RadioSnapshot) -> str | None:
    """What holds the raw IMU below the rate the station wanted, for a too-low rate's reason: a
    radio's budget (an APM 2.5 behind a 57600 SiK radio) or the vehicle's refusal (ArduPlane's
    "Increase SCHED_LOOP_RATE"); None when nothing the station knows of does."""
    name = imu_type or "RAW_IMU"
    row, planned = streams.messages.get(name), radio.streams.get(name)
    if row is None:
        return None
    if radio.present and planned is not None and row.requested_hz < planned.wanted_hz:
        fits, usb = f"{row.requested_hz:g}", f"{planned.wanted_hz:g}"
        return f"{name} asked for at {fits} Hz to fit the radio's budget; over USB it can come at {usb} Hz"
    if row.reason and row.accepted_hz is not None and row.accepted_hz < row.requested_hz:
        return f"asked for at {row.requested_hz:g} Hz: {row.reason}"
    return None


def signing_of(config: StationConfig) -> Signing | None:
    """The MAVLink 2 signing a link of this configuration uses (None: no key, no signing)."""
    key = config.signing_key
    return None if key is None else Signing(key, required=config.signing_required)


def _lower_priority(increment: int) -> None:
    """The worker's initializer: nice it (and import the workbench, so the first call is quick)."""
    if hasattr(os, "nice"):
        os.nice(increment)
    warm_up()


def _call(function: Callable[..., R], args: tuple[Any, ...], kwargs: dict[str, Any]) -> R:
    return function(*args, **kwargs)
