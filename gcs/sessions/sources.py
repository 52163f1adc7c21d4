"""Anything `gcs replay` accepts, decoded once into frames the replay and what-if share.

A source is a recorded session (folder), a .tlog from any ground station, a DataFlash .bin or
a PX4 .ulg. Each becomes a list of `Frame`s: the pacing time, the MAVLink packet to publish on
a bus (tlogs only) and the estimation inputs it carries: samples made by the same
`MessageSampler` the live pipeline uses, plus `GainChange`s where a gain changed (the vehicle's
declination parameter, or a gain change recorded in the session's event log at the pipeline
input position where it was applied live). Feeding those inputs in order to a pipeline built
from `pipeline_config` reproduces the live outputs exactly.
"""

from __future__ import annotations

import json
import os
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gcs.core.estimation import AttitudePoint, EstimationInput, EstimationPipeline, GainChange
from gcs.core.estimators import registry
from gcs.core.samples import AttitudeSample
from gcs.logs.dataflash import DataflashLog
from gcs.logs.logfile import InputError, LogFile
from gcs.logs.ulog import UlogFile
from gcs.mavlink.framing import FramingCounters, MavlinkDecoder
from gcs.mavlink.sampling import INPUT_TYPES, MessageInputs
from gcs.mavlink.tlog import read_tlog_records
from gcs.sessions import layout


@dataclass(slots=True)
class Frame:
    t: float  # pacing time, s: the record's wall time (tlog) or the vehicle time (logs)
    packet: bytes | None  # the MAVLink packet of a tlog record, else None
    sent: bool  # the ground station sent it (tlog link bits 3)
    inputs: tuple[EstimationInput, ...]  # for the estimation pipeline, in order


@dataclass
class ReplaySource:
    path: str
    kind: str  # "session", "tlog", "dataflash", "ulog"
    frames: list[Frame]
    counts: dict[str, int]  # messages / records / rows per type
    span: tuple[float, float] | None  # first and last time on the source's own clock, s
    damage: str | None = None
    pipeline_config: dict = field(default_factory=dict)  # imu_type, system, estimators {name: {preset, gains}}
    meta: dict = field(default_factory=dict)
    framing: FramingCounters | None = None  # tlogs: packets, CRC errors, loss by sequence number
    _inputs: list | None = None
    _references: dict | None = None

    @property
    def duration(self) -> float:
        return 0.0 if not self.frames else self.frames[-1].t - self.frames[0].t

    def inputs(self) -> list[EstimationInput]:
        """Every estimation input in order (cached: what-if runs over this list)."""
        if self._inputs is None:
            self._inputs = [i for frame in self.frames for i in frame.inputs]
        return self._inputs

    def references(self) -> dict[str, np.ndarray]:
        """Reference attitudes {name: N×4 array t, roll, pitch, yaw} (cached: what-if scores against them)."""
        if self._references is None:
            rows: dict[str, list] = {}
            for item in self.inputs():
                if isinstance(item, AttitudeSample):
                    rows.setdefault(item.source, []).append((item.t, item.roll, item.pitch, item.yaw))
            self._references = {name: np.array(r) for name, r in rows.items()}
        return self._references

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

    def replay(
        self,
        pipeline: EstimationPipeline,
        on_points: Callable[[list[AttitudePoint]], None] | None = None,
        progress: Callable[[int, int], None] | None = None,
    ) -> EstimationPipeline:
        """Feed every input to `pipeline` at once (no pacing), handing the points it produces to
        `on_points`; `progress(done, total)` is told every 5000 frames and at the end."""
        total = len(self.frames)
        for done, frame in enumerate(self.frames, start=1):
            for item in frame.inputs:
                points = pipeline.feed(item)
                if points and on_points is not None:
                    on_points(points)
            if progress is not None and done % 5000 == 0:
                progress(done, total)
        if progress is not None:
            progress(total, total)
        return pipeline


def _tlog_frames(
    path: str, config: dict, gain_events: list[tuple[int, GainChange]]
) -> tuple[list[Frame], Counter, str | None, FramingCounters]:
    """Frames of a tlog: one per record; inputs made exactly as the live pipeline makes them."""
    records = read_tlog_records(path)
    decoder = MavlinkDecoder()
    to_inputs = MessageInputs(config.get("imu_type"), config.get("system"))
    pending = sorted(gain_events, key=lambda e: e[0])
    frames: list[Frame] = []
    counts: Counter[str] = Counter()
    position = 0  # estimation input messages so far (the live pipeline's input index)
    for usec, packet in records:
        sent = usec & 3 == 3
        inputs: list[EstimationInput] = []
        for msg in decoder.feed(packet, final=True):
            kind = msg.get_type()
            counts[kind] += 1
            if sent or kind not in INPUT_TYPES:
                continue
            while pending and pending[0][0] <= position:
                inputs.append(pending.pop(0)[1])
            position += 1
            item = to_inputs.feed(msg)
            if item is not None:
                inputs.append(item)
        frames.append(Frame((usec & ~3) / 1e6, packet, sent, tuple(inputs)))
    if pending and frames:
        frames[-1].inputs += tuple(change for _, change in pending)
    if not counts:
        raise InputError(f"{path}: offset 0: no valid MAVLink packet in {len(records.data)} bytes; is this a .tlog?")
    damage = None
    if records.truncated_at is not None:
        damage = f"{path}: offset {records.truncated_at}: last record incomplete; replayed up to it"
    elif records.damage_offsets:
        damage = (
            f"{path}: offset {records.damage_offsets[0]}: {records.skipped} damaged bytes skipped "
            f"({len(records.damage_offsets)} places)"
        )
    return frames, counts, damage, decoder.counters


def _gain_events(folder: Path) -> list[tuple[int, GainChange]]:
    """Gain changes recorded in a session's events.jsonl with the input index they were applied at.
    An incomplete last line (a crash mid-write) is ignored."""
    events: list[tuple[int, GainChange]] = []
    path = folder / layout.EVENTS
    if not path.exists():
        return events
    for line in path.read_text().splitlines():
        try:
            event = json.loads(line)
        except ValueError:
            continue
        if event.get("kind") == "gain" and "input_index" in event:
            events.append((event["input_index"], GainChange(event["estimator"], event["gain"], event["new"])))
    return events


def _log_frames(path: str) -> tuple[list[Frame], dict[str, int], tuple[float, float] | None, str | None]:
    log = LOG_FILES[os.path.splitext(path)[1].lower()](path)
    frames = [Frame(sample.t, None, False, (sample,)) for sample in log]
    span = None if log.first_us is None or log.last_us is None else (log.first_us / 1e6, log.last_us / 1e6)
    return frames, dict(log.counts), span, log.damage


KINDS = {".tlog": "tlog", ".bin": "dataflash", ".ulg": "ulog"}
#: Log files replayed sample by sample (a .tlog is replayed packet by packet).
LOG_FILES: dict[str, type[LogFile]] = {".bin": DataflashLog, ".ulg": UlogFile}


def open_source(path: str | os.PathLike) -> ReplaySource:
    """Decode a session folder, .tlog, .bin or .ulg; InputError names what is wrong and where."""
    path = str(path)
    if os.path.isdir(path):
        folder = Path(path)
        if not layout.is_session(folder):
            raise InputError(f"{path}: not a session folder (no {layout.META})")
        meta = layout.read_meta(folder)
        if "error" in meta:
            raise InputError(meta["error"])
        config = meta.get("estimation") or {}
        tlog = str(folder / layout.TLOG)
        if not os.path.isfile(tlog):
            raise InputError(f"{path}: session has no {layout.TLOG}")
        frames, counts, damage, framing = _tlog_frames(tlog, config, _gain_events(folder))
        return ReplaySource(path, "session", frames, dict(counts), _span(frames), damage, config, meta, framing)
    if not os.path.isfile(path):
        raise InputError(f"{path}: no such file or session folder")
    kind = KINDS.get(os.path.splitext(path)[1].lower())
    if kind is None:
        raise InputError(
            f"{path}: cannot replay {os.path.splitext(path)[1]!r}; give a session folder, .tlog, .bin or .ulg"
        )
    if kind == "tlog":
        frames, tlog_counts, damage, framing = _tlog_frames(path, {}, [])
        return ReplaySource(path, kind, frames, dict(tlog_counts), _span(frames), damage, framing=framing)
    frames, log_counts, span, damage = _log_frames(path)
    return ReplaySource(path, kind, frames, log_counts, span, damage)


def _span(frames: list[Frame]) -> tuple[float, float] | None:
    return (frames[0].t, frames[-1].t) if frames else None


_CACHE: dict[tuple, ReplaySource] = {}
_CACHE_SIZE = 4


def cached_source(path: str | os.PathLike) -> ReplaySource:
    """open_source, remembered while the file (or the session's tlog) is unchanged, so the
    dashboard's what-if and replay controls do not decode the same log twice."""
    key_file = Path(path) / layout.TLOG if os.path.isdir(path) else Path(path)
    try:
        stat = key_file.stat()
    except OSError:
        return open_source(path)  # raises the InputError that names the problem
    key = (str(Path(path).resolve()), stat.st_mtime_ns, stat.st_size)
    if key not in _CACHE:
        if len(_CACHE) >= _CACHE_SIZE:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[key] = open_source(path)
    return _CACHE[key]
