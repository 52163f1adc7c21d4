"""Replay: a recorded session or a foreign log through the estimators, paced or flat out.

`ReplaySession` is what `gcs replay` drives (in its own process): it has a `bus` (tlog packets,
read back from the file, are published there as `Message`s stamped with their recorded wall time),
a `points` signal like `LiveEstimation`'s, and `play()`, `pause()`, `seek(t)`, `set_speed(x)`,
`snapshot()`. Seeking rebuilds the estimators by re-running the inputs from the start without
pacing (they carry state, so there is no other exact way), in chunks that let the loop serve
everything else meanwhile.

The dashboard never plays a replay on the live loop: `replay_series` runs a whole replay in the
station's worker process and returns the encoded series, which each viewer's replay page
(web/public/replay.html) plays by itself, beside the live page (docs/design.md, "Replay").
"""

from __future__ import annotations

import asyncio
import math
import os
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from functools import lru_cache
from itertools import islice

import numpy as np

from gcs.core import strict_json
from gcs.core.estimation import AttitudePoint, EstimationPipeline
from gcs.core.estimators import registry
from gcs.core.estimators.compiled import Compiled
from gcs.core.estimators.whole import run_whole
from gcs.core.samples import REBOOT_CLOCK_JUMP
from gcs.mavlink.framing import MavlinkDecoder
from gcs.mavlink.tlog import MAX_WAIT_S
from gcs.runtime.bus import Message, MessageBus
from gcs.runtime.signal import Signal
from gcs.sessions.scoring import scored
from gcs.sessions.sources import PacketReader, ReplaySource, SourceKey
from gcs.sessions.workbench import workbench

#: Inputs fed between two yields to the loop while seeking or replaying flat out.
CHUNK = 2000


@dataclass(frozen=True)
class ReplaySnapshot:
    path: str
    kind: str
    position_s: float
    duration_s: float
    frame: int
    frames: int
    playing: bool
    finished: bool
    seeking: bool
    speed: float
    damage: str | None


class ReplaySession:
    def __init__(
        self,
        source: ReplaySource,
        speed: float = 1.0,
        estimators: list[str] | None = None,
        gains: dict[str, dict[str, float]] | None = None,
    ) -> None:
        self.source = source
        self.speed = speed  # 0: as fast as possible
        self.estimator_names = estimators
        self.gains = gains or {}
        self.bus = MessageBus()
        self.pipeline = source.new_pipeline(estimators, self.gains)
        self.points: Signal[[list[AttitudePoint]]] = Signal()
        self.position = 0  # index of the next frame
        self._inputs = source.inputs()  # positioned at the next frame's first input
        self.finished = asyncio.Event()
        self._decoder = MavlinkDecoder()
        self._packets: PacketReader | None = None
        self._playing = asyncio.Event()
        self._playing.set()
        self._settled = asyncio.Event()  # no seek in progress
        self._settled.set()
        self._seeks = 0
        self._anchor: tuple[float, float] | None = None  # (monotonic, source time) pacing origin

    # ---- control ---------------------------------------------------------------------
    def play(self) -> None:
        self._anchor = None
        self._playing.set()

    def pause(self) -> None:
        self._playing.clear()

    def set_speed(self, speed: float) -> None:
        if not speed >= 0 or math.isinf(speed):
            raise ValueError(f"speed {speed!r}: give a number >= 0 (0 = as fast as possible)")
        self.speed = speed
        self._anchor = None

    async def seek(self, offset_s: float) -> None:
        """Go to offset_s seconds from the start: the estimators are rebuilt from the start, CHUNK
        inputs at a time, while playing waits. A newer seek supersedes one in progress."""
        t = self.source.frames.t
        if not len(t):
            return
        self._seeks += 1
        ticket = self._seeks
        self._settled.clear()
        after = np.flatnonzero(t >= t[0] + max(0.0, offset_s))
        target = int(after[0]) if len(after) else len(t)
        pipeline = self.source.new_pipeline(self.estimator_names, self.gains)
        inputs = self.source.inputs(0, target)
        while chunk := list(islice(inputs, CHUNK)):
            pipeline.feed_all(chunk)
            await asyncio.sleep(0)
            if ticket != self._seeks:
                return
        self.pipeline, self.position, self._anchor = pipeline, target, None
        self._inputs = self.source.inputs(target)
        if target < len(t):
            self.finished.clear()
        self._settled.set()

    def snapshot(self) -> ReplaySnapshot:
        t = self.source.frames.t
        now = float(t[min(self.position, len(t) - 1)] - t[0]) if len(t) else 0.0
        return ReplaySnapshot(
            path=self.source.path,
            kind=self.source.kind,
            position_s=round(now, 3),
            duration_s=round(self.source.duration, 3),
            frame=self.position,
            frames=len(t),
            playing=self._playing.is_set() and not self.finished.is_set(),
            finished=self.finished.is_set(),
            seeking=not self._settled.is_set(),
            speed=self.speed,
            damage=self.source.damage,
        )

    # ---- playing ---------------------------------------------------------------------
    async def run(self) -> None:
        """Play to the end (then wait for a seek back), honouring pause, speed and seek."""
        try:
            await self._play()
        finally:
            self.close()

    async def _play(self) -> None:
        t = self.source.frames.t
        while True:
            await self._settled.wait()
            if self.position >= len(t):
                self.finished.set()
                await asyncio.sleep(0.1)
                continue
            await self._playing.wait()
            if self.speed > 0:
                due = self._due(float(t[self.position]))
                if due > 0:
                    await asyncio.sleep(min(due, 0.1))
                    continue
            self.step()
            if self.speed == 0 and self.position % CHUNK == 0:
                await asyncio.sleep(0)  # let the server answer while replaying flat out

    def _due(self, t: float) -> float:
        now = time.monotonic()
        if self._anchor is None:
            self._anchor = (now, t)
        due = self._anchor[0] + (t - self._anchor[1]) / self.speed - now
        if abs(due) > MAX_WAIT_S:  # a gap or a damaged stamp: played now, paced on from it
            self._anchor, due = (now, t), 0.0
        return due

    def step(self) -> list[AttitudePoint]:
        """Play one frame now: publish its packet, feed its inputs, tell the listeners."""
        frame = self.position
        self.position += 1
        frames = self.source.frames
        if not frames.sent[frame] and self.bus.subscriptions():
            self._publish(frame, float(frames.t[frame]))
        points: list[AttitudePoint] = []
        for item in islice(self._inputs, int(frames.input_end[frame]) - frames.input_start(frame)):
            points += self.pipeline.feed(item)
        if points:
            self.points.emit(points)
        return points

    def _publish(self, frame: int, wall_time: float) -> None:
        if self._packets is None:
            self._packets = self.source.open_packets()
            if self._packets is None:
                return
        now = time.monotonic()
        for raw, msg_type, sysid, compid in self._decoder.frames(self._packets.packet(frame), final=True):
            self.bus.publish(Message(raw, msg_type, now, wall_time, sysid, compid, "replay"))

    def run_to_end(self, progress: Callable[[int, int], None] | None = None) -> None:
        """Play every remaining frame at once (no pacing): `--fast`, reports, tests."""
        total = len(self.source.frames)
        if not self.bus.subscriptions():
            self._feed_rest(total, progress)
        while self.position < total:
            self.step()
            if progress and self.position % 5000 == 0:
                progress(self.position, total)
        if progress:
            progress(total, total)
        self.finished.set()
        self.close()

    def _feed_rest(self, total: int, progress: Callable[[int, int], None] | None) -> None:
        """Every remaining input in one pass over the columns (nothing to publish)."""
        start = self.position
        frames = self.source.frames
        done = frames.input_start(start)
        for item in self._inputs:
            points = self.pipeline.feed(item)
            if points:
                self.points.emit(points)
            done += 1
            if progress and done % 50_000 == 0:
                progress(int(np.searchsorted(frames.input_end, done, side="left")), total)
        self.position = total

    def close(self) -> None:
        if self._packets is not None:
            self._packets.close()
            self._packets = None


def parse_gains(items: list[str], names: list[str]) -> dict[str, dict[str, float]]:
    """`[EST.]NAME=VALUE` items → {estimator: {gain: value}}; ValueError says which item is wrong."""
    out: dict[str, dict[str, float]] = {}
    for item in items:
        key, sep, text = item.partition("=")
        try:
            value = float(text)
        except ValueError:
            raise ValueError(f"--gain {item!r}: expected [EST.]NAME=VALUE with a number") from None
        if not sep:
            raise ValueError(f"--gain {item!r}: expected [EST.]NAME=VALUE")
        est, dot, gain = key.strip().rpartition(".")
        if dot and est not in names:  # a typo must not look like a gain that was tried
            raise ValueError(f"--gain {item!r}: {est!r} is not a selected estimator ({', '.join(names)})")
        targets = [est] if dot else [n for n in names if any(g.name == gain for g in registry.get(n).GAINS)]
        if not targets:
            raise ValueError(f"--gain {item!r}: no selected estimator ({', '.join(names)}) has a gain {gain!r}")
        for name in targets:
            out.setdefault(name, {})[gain] = value
    return out


def selection(estimators: list[str] | None, gain_items: list[str]) -> tuple[list[str], dict[str, dict[str, float]]]:
    """Estimator names (default: all) and `[EST.]NAME=VALUE` gain items → (names, gains per
    estimator); KeyError names an unknown estimator, ValueError a bad gain item."""
    names = estimators or registry.names()
    for name in names:
        registry.get(name)
    return names, parse_gains(gain_items, names)


def session_table(pipeline: EstimationPipeline) -> list[dict[str, object]]:
    """Session RMS / max error per estimator per reference, degrees (roll, pitch, yaw)."""
    rows: list[dict[str, object]] = []
    for name, comparison in pipeline.comparisons.items():
        for ref, stats in comparison.summary()["references"].items():
            s = stats["session"]
            rows.append({"estimator": name, "reference": ref, "n": s["n"], "rms_deg": s["rms"], "max_deg": s["max"]})
    return rows


def compiled(estimators: list[str]) -> bool:
    """Whether every estimator named has compiled kernels (whole_table can run it)."""
    return all(issubclass(registry.get(name), Compiled) for name in estimators)


def whole_table(
    source: ReplaySource,
    estimators: list[str],
    gains: dict[str, dict[str, float]],
    progress: Callable[[int, int], None] | None = None,
) -> tuple[list[dict[str, object]], int]:
    """`session_table` of a replay to the end, from whole-run arrays (gcs.core.estimators.whole)
    instead of the per-sample pipeline: each estimator in one compiled loop, its outputs then
    scored by the pipeline's own comparison with the references in the order they came
    (gcs.sessions.scoring), so the table is the pipeline's whatever the vehicle clock does (a
    reboot, a log's clock stepping back). For `gcs replay --fast`, where nothing watches the
    frames go by. The estimators are independent and their kernels release the GIL, so each runs
    in its own thread: the replay takes about the slowest one's time on a machine with as many
    cores. Also returns the IMU samples fed (the pipeline's `imu_samples`); progress(done, total)
    counts estimators."""
    workers = max(1, min(len(estimators), os.cpu_count() or 1))
    with ThreadPoolExecutor(workers, thread_name_prefix="whole-run") as pool:
        runs = [pool.submit(_whole_rows, source, name, gains.get(name, {})) for name in estimators]
        for done, _ in enumerate(as_completed(runs), start=1):
            if progress:
                progress(done, len(estimators))
        results = [run.result() for run in runs]
    return [row for rows, _ in results for row in rows], results[-1][1] if results else 0


def _whole_rows(source: ReplaySource, name: str, gains: dict[str, float]) -> tuple[list[dict[str, object]], int]:
    """whole_table's rows of one estimator, and the IMU samples it was fed."""
    table = source.table
    preset, recorded = source.estimator_config(name)
    estimator = registry.create(name, preset, **{**recorded, **gains})
    run = run_whole(estimator, table.kind, table.imu, table.gps, table.gain_change, name)
    rows: list[dict[str, object]] = [
        {"estimator": name, "reference": ref, "n": s["n"], "rms_deg": s["rms"], "max_deg": s["max"]}
        for ref, s in sorted(scored(table, run.q, run.fed).items())
    ]
    return rows, int(run.fed.sum())


#: Replays kept encoded in the worker (a 10-minute session at 50 Hz is a few MB).
SERIES_CACHED = 4
#: s of the replay page's play time between the last moment of one boot and the first of the next.
BOOT_GAP_S = 1.0


@dataclass
class PlayClock:
    """The replay page's play time of attitude points taken in the order recorded: their vehicle
    time, except that after a reboot (the clock back by more than REBOOT_CLOCK_JUMP below the
    newest point of any source) the new boot carries on BOOT_GAP_S after the old one, where its
    clock from 0 would have laid it under it: the page plays the boots one after the other, as
    they happened, instead of all at once. `starts`: the play time at which each boot begins."""

    newest: float = -math.inf
    offset: float = 0.0
    starts: list[float] = field(default_factory=list)

    def of(self, t: float) -> float:
        if not self.starts:
            self.starts.append(round(t, 4))
        elif t < self.newest - REBOOT_CLOCK_JUMP:
            self.offset += self.newest - t + BOOT_GAP_S
            self.newest = t
            self.starts.append(round(t + self.offset, 4))
        self.newest = max(self.newest, t)
        return round(t + self.offset, 4)


def replay_series(path: str | os.PathLike, estimators: list[str], gains: dict[str, dict[str, float]]) -> bytes:
    """A whole replay of the source at path as the replay page's JSON: every source's attitude
    (`{SOURCE: [[t...], [roll...], [pitch...], [yaw...], [play...]]}`, vehicle s and degrees, the
    live frames' columns, then each point's `PlayClock` time), the play time at which each boot of
    the vehicle begins (`boots`) and the session error table. Runs in the station's worker process (the
    source decoded once through its workbench), never on the live loop; InputError, KeyError or
    GainError as the source and the request say."""
    source = workbench().source(path)
    frozen = tuple(sorted((est, tuple(sorted(g.items()))) for est, g in gains.items()))
    if source.key is None:
        return _encoded_series(source, tuple(estimators), frozen)
    return _cached_series(source.key, str(path), tuple(estimators), frozen)


@lru_cache(maxsize=SERIES_CACHED)
def _cached_series(
    key: SourceKey, path: str, estimators: tuple[str, ...], gains: tuple[tuple[str, tuple[tuple[str, float], ...]], ...]
) -> bytes:
    return _encoded_series(workbench().source(path), estimators, gains)


def _encoded_series(
    source: ReplaySource, estimators: tuple[str, ...], gains: tuple[tuple[str, tuple[tuple[str, float], ...]], ...]
) -> bytes:
    session = ReplaySession(source, 0, list(estimators), {est: dict(g) for est, g in gains})
    columns: dict[str, list[list[float]]] = {}
    deg = 180.0 / math.pi
    play = PlayClock()

    def collect(points: list[AttitudePoint]) -> None:
        for p in points:
            cols = columns.get(p.source)
            if cols is None:
                cols = columns[p.source] = [[], [], [], [], []]
            cols[0].append(round(p.t, 4))
            cols[1].append(round(p.roll * deg, 3))
            cols[2].append(round(p.pitch * deg, 3))
            cols[3].append(round(p.yaw * deg, 3))
            cols[4].append(play.of(p.t))

    session.points.connect(collect)
    session.run_to_end()
    return strict_json.dumps(
        {
            "source": os.path.basename(source.path.rstrip("/\\")),
            "kind": source.kind,
            "duration_s": round(source.duration, 3),
            "frames": len(source.frames),
            "imu_samples": session.pipeline.imu_samples,
            "damage": source.damage,
            "estimators": list(session.pipeline.estimators),
            "table": session_table(session.pipeline),
            "points": columns,
            "boots": play.starts,
        },
        separators=(",", ":"),
    ).encode()
