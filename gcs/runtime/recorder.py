"""Records a ground station's session to disk from its first byte.

A `SessionRecorder` belongs to one `Station`. `start()` (before the link runs) closes sessions
a crash left open and waits for the link's first byte: only then is the session folder opened (a
connection that never delivers anything leaves no folder; what happened before, events and packets
sent, is written first). It hooks in: bus → `telemetry.tlog` (received packets, link bits 0) and
the link's sent packets (link bits 3, as MAVProxy marks its own), in one order with
never-decreasing stamps (`TlogClock`); estimation points
→ the `attitude` table, the station's published snapshots (every second) → `comparison`; the event
log → `events.jsonl` (a gain change also carries `input_index`, the estimation input count where a
replay applies it again); vehicle, parameters and estimator configuration → `meta.json`.
The event loop only appends to buffers; a `SessionWriter` thread writes them every 0.25 s.
Session format: docs/design.md
"""

from __future__ import annotations

import asyncio
import logging
import math
import os
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Protocol

from gcs import __version__
from gcs.core import strict_json
from gcs.mavlink.finite import nonfinite_field
from gcs.mavlink.identity import vehicle_label
from gcs.mavlink.params import param_name
from gcs.mavlink.sampling import INPUT_TYPES
from gcs.mavlink.tlog import tlog_record
from gcs.provenance import provenance
from gcs.runtime.bus import MessageBus, Subscription
from gcs.runtime.estimation import LiveEstimation
from gcs.runtime.events import EventLog
from gcs.runtime.link import Link
from gcs.runtime.signal import Signal
from gcs.runtime.snapshots import RecordingSnapshot, StationSnapshot
from gcs.runtime.vehicle import VehicleState
from gcs.sessions import columnar, layout
from gcs.sessions.recovery import close_session, recover_sessions, release_lock, take_lock
from gcs.sessions.writer import SessionWriter

log = logging.getLogger(__name__)

#: Seconds between flushes to the OS: a kill -9 loses at most about this much.
FLUSH_INTERVAL = 0.25
#: Seconds between comparison snapshots and meta.json refreshes.
SNAPSHOT_INTERVAL = 1.0
#: Link bits of a tlog timestamp (MAVProxy convention): 0 received, 3 sent by the ground station.
RECEIVED, SENT = 0, 3
#: Events and sent packets kept while waiting for the first byte (a link that never answers).
EARLY_MAX = 1000
#: VehicleState fields kept in meta.json (the ones that describe the vehicle, not its moment).
VEHICLE_FIELDS = ("sysid", "compid", "autopilot", "vehicle_type", "mavlink_version", "firmware")


def _nan(x: float | None) -> float:
    return math.nan if x is None else x


def tlog_usec(wall_time: float, link_bits: int) -> int:
    """µs UNIX timestamp with the low 2 bits replaced by the link bits."""
    return (int(wall_time * 1e6) & ~3) | link_bits


class TlogClock:
    """Stamps of one .tlog, never decreasing. A received packet carries the wall time its chunk
    was read and a sent packet the time it was sent; a packet sent while a chunk is being parsed
    would otherwise go in between packets stamped earlier (by the parse time), so a stamp below
    the last one is raised to it (by at most that parse time). Link bits included: pymavlink,
    MAVProxy and Mission Planner read the whole stamp as the time, so a received packet raised to
    a sent one's µs (its bits 3) goes 4 µs later, not 3 µs earlier."""

    def __init__(self) -> None:
        self.last = 0

    def stamp(self, wall_time: float, link_bits: int) -> int:
        usec = max(tlog_usec(wall_time, link_bits), (self.last & ~3) | link_bits)
        if usec < self.last:
            usec += 4
        self.last = usec
        return usec


class Session:
    """One session folder being recorded: its writer thread, lock, encoders and meta."""

    def __init__(self, folder: Path, meta: dict, on_error) -> None:
        self.meta = meta
        #: the folder the event log last named (start, renamed): the writer moves it to the vehicle's name
        self.named = folder
        self.encoders = {table: columnar.StreamEncoder(schema) for table, schema in columnar.SCHEMAS.items()}
        self.rows: dict[str, list[tuple]] = {table: [] for table in columnar.SCHEMAS if table != "attitude"}
        self.points: list[tuple[float, list]] = []  # (wall time, AttitudePoints): the attitude table's rows
        self._rows_lock = threading.Lock()
        layout.write_meta(folder, meta)  # at once: the folder is a session (listed, recoverable) from now on
        self.lock_fd = take_lock(folder)
        self.writer = SessionWriter(folder, FLUSH_INTERVAL, on_error, sources=[self._encode_tables])
        self.writer.start()

    @property
    def folder(self) -> Path:
        return self.writer.folder

    def add_rows(self, table: str, rows: list[tuple]) -> None:
        if self.writer.failed is None:
            with self._rows_lock:
                self.rows[table].extend(rows)

    def add_points(self, wall_time: float, points: list) -> None:
        """Estimation points, made rows by the writer thread (the event loop only keeps the list)."""
        if self.writer.failed is None:
            with self._rows_lock:
                self.points.append((wall_time, points))

    def _encode_tables(self) -> dict[str, bytes]:
        with self._rows_lock:
            rows, self.rows = self.rows, {table: [] for table in self.rows}
            points, self.points = self.points, []
        columns: dict[str, list[Sequence]] = {table: list(zip(*table_rows)) for table, table_rows in rows.items()}
        columns["attitude"] = columnar.attitude_columns(points)
        return {
            layout.stream_name(table): encoder.encode_columns(columns[table])
            for table, encoder in self.encoders.items()
        }

    def close(self, end: float) -> dict:
        """Last flush, Parquet conversion, end time in meta; the lock is released."""
        self.writer.close()
        self.meta["end"] = end
        try:
            if self.writer.failed is None:
                self.meta = close_session(self.folder, self.meta, recovered=False)
            else:
                layout.write_meta(self.folder, dict(self.meta, error=str(self.writer.failed)))
        finally:
            release_lock(self.lock_fd)
        return self.meta


class RecordedParts(Protocol):
    """What the recorder reads of the station: the parts whose data goes to disk."""

    link: Link
    bus: MessageBus
    events: EventLog
    vehicle: VehicleState
    estimation: LiveEstimation | None
    published: Signal[[StationSnapshot]]


class SessionRecorder:
    def __init__(self, station: RecordedParts, root: str | os.PathLike) -> None:
        self.station = station
        self.root = Path(root)
        self.session: Session | None = None
        self.state = "off"  # off | waiting (for the first byte) | recording | failed | stopped
        self.error: str | None = None
        self.recovered: list[dict] = []
        self.packets = {"received": 0, "sent": 0}
        self.params: dict[str, float] = {}
        self._sub: Subscription | None = None
        self._input_base = 0  # bus input messages published before the session's first tlog record
        self._meta_dirty = False
        self._loop: asyncio.AbstractEventLoop | None = None
        self._clock = TlogClock()
        self._armed = False  # open a session at the link's first byte
        self._early_events: list[bytes] = []  # event lines and sent tlog records from before it
        self._early_sent: list[bytes] = []
        station.link.packet_sent.connect(self._on_send)
        station.events.recorded.connect(self._on_event)
        if station.estimation is not None:
            station.estimation.points.connect(self._on_points)
        station.published.connect(self._on_published)

    # ---- lifecycle ---------------------------------------------------------------------
    def start(self) -> None:
        """Recover abandoned sessions, then wait for the link's first byte to open a new one.
        Errors are reported, not raised."""
        try:
            self._loop = asyncio.get_running_loop()
        except RuntimeError:
            self._loop = None
        columnar.warm()  # not in the writer thread, with the link running
        try:
            self.root.mkdir(parents=True, exist_ok=True)
            self.recovered = recover_sessions(self.root)
        except OSError as exc:
            self.report_error(f"cannot use recording folder {self.root}: {exc.strerror or exc}")
            return
        self.state, self._armed = "waiting", True
        if self._sub is None:
            self._sub = self.station.bus.subscribe("recorder", maxlen=200_000)
        for report in self.recovered:
            self.station.events.record("recording", "recorder", event="recovered", **report)

    def start_recording(self, start: float | None = None) -> None:
        """Open a new session folder now (the dashboard's "start recording")."""
        if self.state == "recording":
            return
        self.stop_recording()  # a session stopped by an error is closed before the next one opens
        self._armed, self._early_events, self._early_sent = False, [], []
        start = time.time() if start is None else start
        folder = layout.unique_folder(self.root, layout.folder_name(start, self._vehicle_label() or "unknown"))
        try:
            folder.mkdir(parents=True)
            self.session = Session(folder, self._initial_meta(start), self._on_writer_error)
        except OSError as exc:
            self.report_error(f"cannot create session folder {folder}: {exc.strerror or exc}")
            return
        self.state, self.error = "recording", None
        self.packets = {"received": 0, "sent": 0}
        if self._sub is None:
            self._sub = self.station.bus.subscribe("recorder", maxlen=200_000)
        self._sub.drain()  # published before this session: not in its tlog
        # Input positions of this session count from here, as its replay counts from the tlog's start.
        self._input_base = self.station.bus.inputs_published
        self.station.events.record("recording", "recorder", event="start", folder=str(folder))

    def _open_at_first_byte(self, items: list) -> None:
        """The first received packets are here: open the session with them as its tlog's start,
        after what was recorded while waiting (events, packets sent)."""
        early_events, early_sent = self._early_events, self._early_sent
        self._early_events, self._early_sent = [], []
        self.start_recording(start=items[0].wall_time)
        session = self.session
        if session is None:
            return
        self._input_base -= sum(item.type in INPUT_TYPES for item in items)  # they are in its tlog
        session.writer.append(layout.EVENTS, b"".join(early_events))
        session.writer.append(layout.TLOG, b"".join(early_sent))
        self.packets["sent"] += len(early_sent)

    def stop_recording(self, client: str = "recorder") -> dict | None:
        """Stop and close the current session now (blocking: the station's shutdown); returns its meta."""
        session = self.detach(client)
        if session is None:
            return None
        try:
            return self.finish(session)
        except OSError as exc:
            self.report_error(f"cannot close session {session.folder}: {exc.strerror or exc}")
            return None

    def detach(self, client: str = "recorder") -> Session | None:
        """Stop feeding the current session (in the event loop); close it with `finish`."""
        self._armed = False
        if self.state == "waiting":
            self.state = "stopped"
        session = self.session
        if session is None:
            return None
        if self.station.estimation is not None:  # inputs delivered but not yet estimated: now, into this session
            self.station.estimation.catch_up()
        self._note_rename(session)
        self.station.events.record("recording", client, event="stop", folder=str(session.folder))
        self._drain()
        self.session = None
        self.state = "stopped" if self.state == "recording" else self.state
        return session

    @staticmethod
    def finish(session: Session) -> dict:
        """Close a detached session: last flush, Parquet, end time. Blocking disk work, so a request
        handler runs it in a worker thread. OSError if the folder cannot be written."""
        return session.close(time.time())

    async def run(self) -> None:
        """Move received packets from the bus to the writer; refresh meta and snapshots."""
        next_snapshot = time.monotonic() + SNAPSHOT_INTERVAL
        while True:
            await asyncio.sleep(FLUSH_INTERVAL / 2)
            self._drain()
            if time.monotonic() >= next_snapshot:
                next_snapshot += SNAPSHOT_INTERVAL
                self._snapshot()

    def close(self) -> None:
        """Stop recording and unhook from the bus (Station.stop calls this)."""
        self.stop_recording()
        if self._sub is not None:
            self._sub.close()
            self._sub = None

    def snapshot(self) -> RecordingSnapshot:
        """What the dashboard shows: state, folder, size, counts, and the error if any."""
        session = self.session
        writer = session.writer if session else None
        return RecordingSnapshot(
            state=self.state,
            folder=str(session.folder) if session else None,
            root=str(self.root),
            bytes_written=writer.bytes_written if writer else 0,
            last_flush_age_s=(
                round(time.monotonic() - writer.last_flush, 3) if writer and writer.last_flush is not None else None
            ),
            packets_received=self.packets["received"],
            packets_sent=self.packets["sent"],
            dropped=self._sub.dropped if self._sub else 0,
            error=self.error,
            recovered=list(self.recovered),
        )

    def note(self, text: str, client: str) -> bool:
        """A user's note, kept in the session's event log; False, and not taken, when no session
        is recording or waiting to (the note would be in none)."""
        if self.session is None and not self._armed:
            return False
        self.station.events.record("note", client, text=text)
        return True

    # ---- producers (event loop) --------------------------------------------------------
    def _drain(self) -> None:
        if self._sub is None:
            return
        items = self._sub.drain()
        if self.session is None and self._armed and items:
            self._open_at_first_byte(items)
        session = self.session
        if session is None or not items:
            return
        parts = []
        for item in items:
            parts.append(tlog_record(self._clock.stamp(item.wall_time, RECEIVED), item.raw))
            if item.type == "PARAM_VALUE":
                self._on_param(item.msg)
        session.writer.append(layout.TLOG, b"".join(parts))
        self.packets["received"] += len(items)

    def _on_published(self, snapshot: StationSnapshot) -> None:
        """Session error statistics of every estimator, one row per reference, per snapshot."""
        if self.session is None or snapshot.estimation is None:
            return
        rows = [
            (
                snapshot.published,
                name,
                ref,
                s.n,
                *map(_nan, s.session_rms_deg),
                *map(_nan, s.session_max_deg),
                _nan(est.lag_s),
                est.imu_rate_hz,
            )
            for name, est in snapshot.estimation.estimators.items()
            for ref, s in est.errors.items()
        ]
        self.session.add_rows("comparison", rows)

    def _on_send(self, packet: bytes) -> None:
        """A sent packet goes after every packet received before it (drained first), stamped now."""
        self._drain()
        record = tlog_record(self._clock.stamp(time.time(), SENT), packet)
        if self.session is not None:
            self.session.writer.append(layout.TLOG, record)
            self.packets["sent"] += 1
        elif self._armed and len(self._early_sent) < EARLY_MAX:
            self._early_sent.append(record)

    def _on_points(self, points) -> None:
        if self.session is None and self._armed:
            # estimated from packets the recorder holds but has not drained yet: they open the
            # session now, or a warm estimator's first points would come before it and be lost
            self._drain()
        if self.session is not None:
            self.session.add_points(time.time(), points)

    def _on_event(self, event) -> None:
        if self.session is None and not self._armed:
            return
        line = event.as_dict()
        if event.kind == "gain" and self.station.estimation is not None:
            line["input_index"] = max(0, self.station.estimation.messages_fed - self._input_base)
        encoded = (strict_json.dumps(line, default=str) + "\n").encode()
        if self.session is not None:
            self.session.writer.append(layout.EVENTS, encoded)
        elif len(self._early_events) < EARLY_MAX:
            self._early_events.append(encoded)

    def _on_param(self, msg) -> None:
        if nonfinite_field(msg, "PARAM_VALUE") is not None:
            return  # the link checks it only when a part reads parameters: the recorder reads it here
        name = param_name(msg)
        if name not in self.params:
            self.params[name] = float(msg.param_value)
            self._meta_dirty = True

    def _snapshot(self) -> None:
        session = self.session
        if session is None:
            return
        self._note_rename(session)
        estimation = self.station.estimation
        if estimation is not None:
            session.meta["estimation"]["detected_imu_type"] = estimation.imu_type
        vehicle = self._vehicle()
        if vehicle != session.meta["vehicle"] or self._meta_dirty:
            session.meta["vehicle"] = vehicle
            session.meta["params"] = dict(self.params)
            self._meta_dirty = False
            session.writer.set_meta(dict(session.meta))
            label = vehicle.get("label")
            name = layout.labelled(session.folder.name, label) if label else None
            if name is not None:
                session.writer.rename_folder(layout.unique_folder(self.root, name))

    # ---- helpers -----------------------------------------------------------------------
    def _note_rename(self, session: Session) -> None:
        """The writer moved the folder to the vehicle's name (at a flush after `rename_folder`): an
        event says where, since the start event named a folder that no longer exists ("..._unknown")."""
        if session.folder != session.named:
            old, session.named = session.named, session.folder
            self.station.events.record(
                "recording", "recorder", event="renamed", old=str(old), folder=str(session.folder)
            )

    def _vehicle_label(self) -> str | None:
        v = self.station.vehicle
        if not v.heartbeats:
            return None
        return vehicle_label(v.autopilot, v.vehicle_type, self.station.link.target_system)

    def _vehicle(self) -> dict:
        """The session's vehicle fields (scalars, read off the snapshot: a `dataclasses.asdict` of it
        copied its track and messages every second too, 2.9 ms of the loop's time after 15 minutes
        of GPS, against 0.012 ms for these)."""
        state = self.station.vehicle.snapshot()
        return {"label": self._vehicle_label(), **{k: getattr(state, k) for k in VEHICLE_FIELDS}}

    def _initial_meta(self, start: float) -> dict:
        link = self.station.link
        estimation = self.station.estimation
        return {
            "format": "gcs-session/1",
            "start": start,
            "end": None,
            "pid": os.getpid(),
            "gcs_version": __version__,
            "provenance": provenance().as_json(),
            "link": {"address": str(link.address), "baud": link.snapshot().baud},  # None but on serial
            "vehicle": self._vehicle(),
            "estimation": None
            if estimation is None
            else {
                "imu_type": estimation.inputs.sampler.imu_type,
                "system": estimation.inputs.sampler.system,
                "detected_imu_type": None,
                "estimators": {
                    name: {"preset": est.preset, "gains": dict(est.gains.values)}
                    for name, est in estimation.pipeline.estimators.items()
                },
            },
            "params": dict(self.params),
            "recovered": False,
        }

    def _on_writer_error(self, exc: Exception, name: str) -> None:
        """From the writer thread: report in the loop (events, status), once."""
        reason = (exc.strerror or str(exc)) if isinstance(exc, OSError) else f"{type(exc).__name__}: {exc}"
        message = f"recording stopped: cannot write {name}: {reason}; what was written is kept"
        if self._loop is not None and not self._loop.is_closed():
            self._loop.call_soon_threadsafe(self.report_error, message)
        else:
            self.report_error(message)

    def report_error(self, message: str) -> None:
        self.state, self.error = "failed", message
        log.error("%s", message)
        self.station.events.record("recording", "recorder", event="error", error=message)
