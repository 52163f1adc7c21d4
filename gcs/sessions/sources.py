"""Anything `gcs replay` accepts, decoded once into columns the replay and what-if share.

A source is a recorded session (folder), a .tlog from any ground station, a DataFlash .bin or
a PX4 .ulg. It becomes `Frames` (per tlog record or log sample: pacing time, where its MAVLink
packet is in the file, whether the ground station sent it, where its inputs end) and an
`InputTable` of estimation inputs: samples made by the same `MessageInputs` the live pipeline
uses, plus `GainChange`s where a gain changed (the vehicle's declination parameter, or a gain
change recorded in the session's event log at the pipeline input position where it was applied
live). Feeding those inputs in order to `new_pipeline()` reproduces the live outputs exactly.
Packets stay in the file and are read back only when a replay publishes them.
"""

from __future__ import annotations

import json
import os
from array import array
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import BinaryIO

import numpy as np
import numpy.typing as npt

from gcs.core.estimation import AttitudePoint, EstimationInput, EstimationPipeline, GainChange
from gcs.core.estimators import registry
from gcs.core.estimators.whole import InputKind as Kind
from gcs.core.plausibility import attitude_rows_accepted
from gcs.logs.dataflash import DataflashLog, DataflashTextLog
from gcs.logs.input_table import InputTable, InputTableBuilder
from gcs.logs.logfile import InputError, LogFile, no_imu_samples
from gcs.logs.tlog import no_imu
from gcs.logs.ulog import UlogFile
from gcs.mavlink.decoding import decode
from gcs.mavlink.dialect import MAVLinkMessage
from gcs.mavlink.firmware_version import banner_version, version_of
from gcs.mavlink.framing import FramingCounters, MavlinkDecoder
from gcs.mavlink.identity import heartbeat_label, is_vehicle_heartbeat
from gcs.mavlink.sampling import IMU_TYPES, INPUT_TYPES, SAMPLED_TYPES, MessageInputs
from gcs.mavlink.tlog import packet_length, read_tlog_records
from gcs.sessions import layout

#: A source's identity for caches: resolved path, mtime (ns) and size of the file decoded.
SourceKey = tuple[str, int, int]


@dataclass(frozen=True, eq=False)
class Frames:
    """One row per tlog record (or log sample), in file order.

    t: pacing time, s (the record's wall time for a tlog, the vehicle time for a log).
    offset: file offset of the record's MAVLink packet (tlogs), or None (logs: no packets).
    sent: the ground station sent it (tlog link bits 3). input_end: frame i's inputs are
    input_end[i-1] (0 for the first) up to input_end[i].
    """

    t: npt.NDArray[np.float64]
    offset: npt.NDArray[np.int64] | None
    sent: npt.NDArray[np.bool_]
    input_end: npt.NDArray[np.int64]

    def __len__(self) -> int:
        return len(self.t)

    def input_start(self, frame: int) -> int:
        return 0 if frame == 0 else int(self.input_end[frame - 1])

    @property
    def nbytes(self) -> int:
        return (
            self.t.nbytes
            + self.sent.nbytes
            + self.input_end.nbytes
            + (0 if self.offset is None else self.offset.nbytes)
        )


@dataclass
class ReplaySource:
    path: str
    kind: str  # "session", "tlog", "dataflash", "ulog"
    frames: Frames
    table: InputTable
    counts: dict[str, int]  # messages / records / rows per type
    span: tuple[float, float] | None  # first and last time on the source's own clock, s
    damage: str | None = None
    pipeline_config: dict = field(default_factory=dict)  # imu_type, system, estimators {name: {preset, gains}}
    meta: dict = field(default_factory=dict)
    framing: FramingCounters | None = None  # tlogs: packets, CRC errors, loss by sequence number
    packet_file: str | None = None  # the tlog the frames' packet offsets point into
    key: SourceKey | None = None
    #: what a .bin, .log or .ulg lacks (no MAG records: heading from the gyro only ...), LogFile.notes
    notes: list[str] = field(default_factory=list)

    @property
    def duration(self) -> float:
        t = self.frames.t
        return 0.0 if not len(t) else float(t[-1] - t[0])

    @property
    def nbytes(self) -> int:
        """Bytes of array data held (frames and inputs)."""
        return self.frames.nbytes + self.table.nbytes

    def require_imu(self) -> None:
        """InputError when the source holds no IMU sample, so no estimate can be made from it: a
        .bin's, .log's or .ulg's reader refuses one as it opens; a .tlog or session opens (its
        messages still export and replay to the dashboard), and a run of the estimators asks this."""
        path = self.packet_file or self.path
        if not len(self.table.imu):  # as `gcs estimate` tells a log with no IMU message from one whose gave none
            raise no_imu_samples(path) if set(IMU_TYPES) & set(self.counts) else no_imu(path, IMU_TYPES)

    def inputs(self, start_frame: int = 0, stop_frame: int | None = None) -> Iterator[EstimationInput]:
        """The estimation inputs of frames start_frame..stop_frame-1 (default: all), in order."""
        stop_frame = len(self.frames) if stop_frame is None else stop_frame
        if stop_frame <= start_frame:
            return iter(())
        start = self.frames.input_start(start_frame)
        return self.table.inputs(start, int(self.frames.input_end[stop_frame - 1]))

    def input_wall_times(self) -> npt.NDArray[np.float64]:
        """Per input (`table.inputs()` order), the UNIX time (s) of the tlog record it came in;
        NaN for a log, whose frames run on the vehicle's clock."""
        n = len(self.table)
        if self.frames.offset is None:
            return np.full(n, np.nan)
        return self.frames.t[np.searchsorted(self.frames.input_end, np.arange(n), side="right")]

    @cached_property
    def references(self) -> dict[str, npt.NDArray[np.float64]]:
        """Reference attitudes {name: N×4 array t, roll, pitch, yaw}: what-if and `gcs replay
        --fast` score against them; those the pipeline refuses (non-finite, beyond ±2π) left out."""
        return {name: rows[attitude_rows_accepted(rows)] for name, rows in self.table.references().items()}

    def open_packets(self) -> PacketReader | None:
        """A reader of the frames' MAVLink packets, or None when the source has none (logs)."""
        if self.packet_file is None or self.frames.offset is None:
            return None
        return PacketReader(self.packet_file, self.frames.offset)

    def estimator_config(self, name: str) -> tuple[str | None, dict[str, float]]:
        """(preset, gains) the estimator ran with at the start of the source."""
        conf = self.pipeline_config.get("estimators", {}).get(name, {})
        return conf.get("preset"), dict(conf.get("gains", {}))

    def new_pipeline(
        self, names: list[str] | None = None, overrides: dict[str, dict[str, float]] | None = None
    ) -> EstimationPipeline:
        """A pipeline as the source's live one started (recorded presets and gains), with only
        `names` (default: every registered estimator) and gain overrides per estimator."""
        overrides = overrides or {}
        estimators = {}
        for name in names or registry.names():
            preset, gains = self.estimator_config(name)
            estimators[name] = registry.create(name, preset, **{**gains, **overrides.get(name, {})})
        return EstimationPipeline(estimators)

    def outputs(
        self, pipeline: EstimationPipeline, progress: Callable[[int, int], None] | None = None
    ) -> Iterator[tuple[int, list[AttitudePoint]]]:
        """Feed every input to `pipeline` in order, at once (no pacing), yielding (input index,
        points) for each input that made points; `progress(done, total)` is told every 50000
        inputs and at the end."""
        total = len(self.table)
        for index, item in enumerate(self.table.inputs()):
            points = pipeline.feed(item)
            if points:
                yield index, points
            if progress is not None and (index + 1) % 50_000 == 0:
                progress(index + 1, total)
        if progress is not None:
            progress(total, total)

    def replay(
        self,
        pipeline: EstimationPipeline,
        on_points: Callable[[list[AttitudePoint]], None] | None = None,
        progress: Callable[[int, int], None] | None = None,
    ) -> EstimationPipeline:
        """`outputs`, handing each input's points to `on_points`; returns the pipeline."""
        for _, points in self.outputs(pipeline, progress):
            if on_points is not None:
                on_points(points)
        return pipeline


class PacketReader:
    """Reads frame i's MAVLink packet back from the tlog (buffered: sequential reads are cheap)."""

    def __init__(self, path: str, offsets: npt.NDArray[np.int64]) -> None:
        self._file: BinaryIO = open(path, "rb")
        self._offsets = offsets

    def packet(self, frame: int) -> bytes:
        offset = int(self._offsets[frame])
        if self._file.tell() != offset:
            self._file.seek(offset)
        head = self._file.read(3)
        length = packet_length(head, 0)
        if length is None:
            raise InputError(f"{self._file.name}: offset {offset}: the file changed since it was decoded")
        return head + self._file.read(length - 3)

    def close(self) -> None:
        self._file.close()


class _FramesBuilder:
    def __init__(self, with_packets: bool) -> None:
        self.t, self.offset, self.sent, self.input_end = array("d"), array("q"), array("b"), array("q")
        self.with_packets = with_packets

    def append(self, t: float, offset: int, sent: bool, input_end: int) -> None:
        self.t.append(t)
        if self.with_packets:
            self.offset.append(offset)
        self.sent.append(sent)
        self.input_end.append(input_end)

    def build(self) -> Frames:
        return Frames(
            np.frombuffer(self.t, dtype=np.float64),
            np.frombuffer(self.offset, dtype=np.int64) if self.with_packets else None,
            np.frombuffer(self.sent, dtype=np.bool_),
            np.frombuffer(self.input_end, dtype=np.int64),
        )


@dataclass
class _Decoded:
    frames: Frames
    table: InputTable
    counts: dict[str, int]
    damage: str | None
    framing: FramingCounters | None = None
    span: tuple[float, float] | None = None
    #: the replayed vehicle's name (a tlog's from its HEARTBEAT, a log's from what it says of it)
    #: and its firmware's version, as a session's meta names them
    vehicle: str | None = None
    firmware: str | None = None
    notes: list[str] = field(default_factory=list)

    def meta(self) -> dict:
        """What a session's meta.json would say of the vehicle, for a bare log: only what it said."""
        known = {"label": self.vehicle, "firmware": self.firmware}
        vehicle = {k: v for k, v in known.items() if v}
        return {"vehicle": vehicle} if vehicle else {}


def _decode_tlog(path: str, config: dict, gain_events: list[tuple[int, GainChange]]) -> _Decoded:
    """Frames of a tlog: one per record; inputs made exactly as the live pipeline makes them."""
    records = read_tlog_records(path)
    decoder = MavlinkDecoder()
    to_inputs = MessageInputs(config.get("imu_type"), config.get("system"))
    pending = sorted(gain_events, key=lambda e: e[0])
    frames = _FramesBuilder(with_packets=True)
    table = InputTableBuilder()
    counts: Counter[str] = Counter()
    labels: dict[int, str] = {}  # each vehicle's name, from its first HEARTBEAT
    firmwares: dict[int, str] = {}  # each vehicle's firmware, from its banner or AUTOPILOT_VERSION
    position = 0  # estimation input messages so far (the live pipeline's input index)
    for offset, usec, packet in records.records():
        sent = usec & 3 == 3
        for raw, kind, _, _ in decoder.frames(packet, final=True):
            counts[kind] += 1
            if kind == "HEARTBEAT" and not sent and counts[kind] <= LABEL_HEARTBEATS:
                _name_vehicle(decode(raw), labels)
            elif kind in FIRMWARE_TYPES and not sent:
                _note_firmware(decode(raw), firmwares)
            if sent or kind not in SAMPLED_TYPES:  # framed and counted, not decoded
                continue
            while pending and pending[0][0] <= position:
                table.append(pending.pop(0)[1])
            position += kind in INPUT_TYPES
            for item in to_inputs.feed(decode(raw), (usec & ~3) / 1e6):
                table.append(item)
        frames.append((usec & ~3) / 1e6, offset, sent, len(table))
    if pending and frames.t:
        for _, change in pending:
            table.append(change)
        frames.input_end[-1] = len(table)
    if not counts:
        raise InputError(f"{path}: offset 0: no valid MAVLink packet in {records.size} bytes; is this a .tlog?")
    damage = records.damage("replayed up to it")
    built = frames.build()
    span = (float(built.t[0]), float(built.t[-1])) if len(built) else None
    sampler = to_inputs.sampler
    replayed = sampler.system if sampler.system is not None else sampler.attitude_system
    sysid = replayed if replayed is not None else next(iter(labels), -1)  # else the first vehicle heard
    vehicle, firmware = labels.get(sysid), firmwares.get(sysid)
    return _Decoded(built, table.build(), dict(counts), damage, decoder.counters, span, vehicle, firmware)


#: HEARTBEATs of a tlog looked at for its vehicles' names (the first few: each system sends one a second)
LABEL_HEARTBEATS = 100


def _name_vehicle(msg: MAVLinkMessage, labels: dict[int, str]) -> None:
    """The vehicle's name from its first HEARTBEAT (ground stations' and companions' are none)."""
    if msg.get_srcSystem() not in labels and is_vehicle_heartbeat(msg):
        labels[msg.get_srcSystem()] = heartbeat_label(msg)


#: What names a vehicle's firmware in a tlog (as the live vehicle state reads it)
FIRMWARE_TYPES = ("STATUSTEXT", "AUTOPILOT_VERSION")


def _note_firmware(msg: MAVLinkMessage, firmwares: dict[int, str]) -> None:
    """The firmware's version as the live state takes it: the first banner, else AUTOPILOT_VERSION."""
    sysid, known = msg.get_srcSystem(), firmwares.get(msg.get_srcSystem())
    if msg.get_type() == "STATUSTEXT":
        banner = banner_version(msg.text)
        if banner is not None and (known is None or known[0].isdigit()):
            firmwares[sysid] = banner
    elif known is None:
        firmwares[sysid] = version_of(msg)


def _gain_events(folder: Path) -> list[tuple[int, GainChange]]:
    """Gain changes recorded in a session's events.jsonl with the input index they were applied at.
    An incomplete last line (a crash mid-write) is ignored, and a damaged one as read_events reads it."""
    events: list[tuple[int, GainChange]] = []
    path = layout.session_file(folder, layout.EVENTS)
    if not path.exists():
        return events
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        try:
            event = json.loads(line)
        except ValueError:
            continue
        if event.get("kind") == "gain" and "input_index" in event:
            events.append((event["input_index"], GainChange(event["estimator"], event["gain"], event["new"])))
    return events


def _decode_log(path: str) -> _Decoded:
    """Frames of a DataFlash or ULog file: one per sample, paced on the vehicle clock."""
    log = LOG_FILES[os.path.splitext(path)[1].lower()](path)
    table = log.columns()
    span = None if log.first_us is None or log.last_us is None else (log.first_us / 1e6, log.last_us / 1e6)
    return _Decoded(
        sample_frames(table),
        table,
        dict(log.counts),
        log.damage,
        span=span,
        vehicle=log.vehicle,
        firmware=log.firmware,
        notes=list(log.notes),
    )


def sample_frames(table: InputTable) -> Frames:
    """One frame per input that is a sample, at its time; a gain change (untimed) goes with the
    next frame's inputs, those after the last sample with the last frame's."""
    t = np.empty(len(table))
    kind = table.kind
    t[(kind == Kind.IMU) | (kind == Kind.IMU_MAG)] = table.imu[:, 0]
    t[(kind == Kind.GPS) | (kind == Kind.GPS_VEL)] = table.gps[:, 0]
    t[kind == Kind.ATTITUDE] = table.attitude[:, 0]
    samples = np.flatnonzero(kind != Kind.GAIN)
    input_end = samples + 1
    if len(input_end):
        input_end[-1] = len(table)
    return Frames(t[samples], None, np.zeros(len(samples), dtype=np.bool_), input_end.astype(np.int64))


KINDS = {".tlog": "tlog", ".bin": "dataflash", ".log": "dataflash", ".ulg": "ulog"}
#: Log files replayed sample by sample (a .tlog is replayed packet by packet).
LOG_FILES: dict[str, type[LogFile]] = {".bin": DataflashLog, ".log": DataflashTextLog, ".ulg": UlogFile}


def decoded_file(path: str | os.PathLike) -> Path:
    """The file a source's content comes from: the session's tlog for a folder, else the path."""
    return Path(path) / layout.TLOG if os.path.isdir(path) else Path(path)


def source_key(path: str | os.PathLike) -> SourceKey | None:
    """(resolved path, mtime ns, size) of the decoded file; None when it cannot be read."""
    try:
        stat = decoded_file(path).stat()
    except OSError:
        return None
    return (str(Path(path).resolve()), stat.st_mtime_ns, stat.st_size)


def open_source(path: str | os.PathLike) -> ReplaySource:
    """Decode a session folder, .tlog, .bin or .ulg; InputError names what is wrong and where."""
    path = str(path)
    key = source_key(path)
    if os.path.isdir(path):
        folder = Path(path)
        if not layout.is_session(folder):
            raise InputError(f"{path}: not a session folder (no {layout.META})")
        meta = layout.read_meta(folder)
        if "error" in meta:
            raise InputError(meta["error"])
        config = meta.get("estimation") or {}
        tlog = str(layout.session_file(folder, layout.TLOG))
        if not os.path.isfile(tlog):
            raise InputError(f"{path}: session has no {layout.TLOG}")
        d = _decode_tlog(tlog, config, _gain_events(folder))
        return ReplaySource(
            path, "session", d.frames, d.table, d.counts, d.span, d.damage, config, meta, d.framing, tlog, key
        )
    if not os.path.isfile(path):
        raise InputError(f"{path}: no such file or session folder")
    kind = KINDS.get(os.path.splitext(path)[1].lower())
    if kind is None:
        raise InputError(
            f"{path}: cannot replay {os.path.splitext(path)[1]!r}; give a session folder, .tlog, .bin, .log or .ulg"
        )
    if kind == "tlog":
        d = _decode_tlog(path, {}, [])
        meta = d.meta()
        return ReplaySource(
            path,
            kind,
            d.frames,
            d.table,
            d.counts,
            d.span,
            d.damage,
            meta=meta,
            framing=d.framing,
            packet_file=path,
            key=key,
        )
    d = _decode_log(path)
    return ReplaySource(
        path, kind, d.frames, d.table, d.counts, d.span, d.damage, meta=d.meta(), key=key, notes=d.notes
    )
