"""Replay: a recorded session or a foreign log through sensors → estimators → comparison,
with play, pause, seek and speed, and `gcs replay`.

`ReplaySession` is what the server drives: it has a `bus` (tlog packets are published there as
`Message`s stamped with their recorded wall time, so the dashboard shows them as it shows a live
link), an `add_listener(cb(points))` like `LiveEstimation`, and `play()`, `pause()`, `seek(t)`,
`set_speed(x)`, `status()`. Seeking rebuilds the estimators by re-running the inputs from the
start without pacing (they carry state, so there is no other exact way).
"""

from __future__ import annotations

import argparse
import asyncio
import math
import sys
import time
from typing import Callable

from gcs.bus import Message, MessageBus, vehicle_time_of
from gcs.link.framing import MavlinkDecoder
from gcs.sessions.sources import ReplaySource, apply


class ReplaySession:
    def __init__(self, source: ReplaySource, speed: float = 1.0, estimators: list[str] | None = None,
                 gains: dict[str, dict[str, float]] | None = None) -> None:
        self.source = source
        self.speed = speed  # 0: as fast as possible
        self.estimator_names = estimators
        self.gains = gains or {}
        self.bus = MessageBus()
        self.pipeline = source.new_pipeline(estimators, self.gains)
        self.position = 0  # index of the next frame
        self.finished = asyncio.Event()
        self._decoder = MavlinkDecoder()
        self._listeners: list[Callable[[list], None]] = []
        self._playing = asyncio.Event()
        self._playing.set()
        self._anchor: tuple[float, float] | None = None  # (monotonic, source time) pacing origin

    # ---- control ---------------------------------------------------------------------
    def add_listener(self, callback: Callable[[list], None]) -> None:
        self._listeners.append(callback)

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

    def seek(self, offset_s: float) -> None:
        """Go to offset_s seconds from the start: the estimators are rebuilt from the start."""
        frames = self.source.frames
        if not frames:
            return
        target_t = frames[0].t + max(0.0, offset_s)
        self.pipeline = self.source.new_pipeline(self.estimator_names, self.gains)
        self.position = 0
        while self.position < len(frames) and frames[self.position].t < target_t:
            for item in frames[self.position].inputs:
                apply(self.pipeline, item)
            self.position += 1
        self._anchor = None
        if self.position < len(frames):
            self.finished.clear()

    def status(self) -> dict:
        frames = self.source.frames
        start = frames[0].t if frames else 0.0
        now = frames[min(self.position, len(frames) - 1)].t - start if frames else 0.0
        return {
            "path": self.source.path, "kind": self.source.kind,
            "position_s": round(now, 3), "duration_s": round(self.source.duration, 3),
            "frame": self.position, "frames": len(frames),
            "playing": self._playing.is_set() and not self.finished.is_set(),
            "finished": self.finished.is_set(), "speed": self.speed, "damage": self.source.damage,
        }

    # ---- playing ---------------------------------------------------------------------
    async def run(self) -> None:
        """Play to the end (then wait for a seek back), honouring pause, speed and seek."""
        frames = self.source.frames
        while True:
            if self.position >= len(frames):
                self.finished.set()
                await asyncio.sleep(0.1)
                continue
            await self._playing.wait()
            if self.speed > 0:
                due = self._due(frames[self.position].t)
                if due > 0:
                    await asyncio.sleep(min(due, 0.1))
                    continue
            self.step()
            if self.speed == 0 and self.position % 2000 == 0:
                await asyncio.sleep(0)  # let the server answer while replaying flat out

    def _due(self, t: float) -> float:
        now = time.monotonic()
        if self._anchor is None:
            self._anchor = (now, t)
        return self._anchor[0] + (t - self._anchor[1]) / self.speed - now

    def step(self) -> list:
        """Play one frame now: publish its packet, feed its inputs, tell the listeners."""
        frame = self.source.frames[self.position]
        self.position += 1
        if frame.packet is not None and not frame.sent and self.bus.subscriptions():
            now = time.monotonic()
            for msg in self._decoder.feed(frame.packet, final=True):
                header = msg.get_header()
                self.bus.publish(Message(msg, msg.get_type(), now, frame.t, vehicle_time_of(msg),
                                         header.srcSystem, header.srcComponent, "replay"))
        points = []
        for item in frame.inputs:
            points += apply(self.pipeline, item)
        if points:
            for callback in self._listeners:
                callback(points)
        return points

    def run_to_end(self, progress: Callable[[int, int], None] | None = None) -> None:
        """Play every remaining frame at once (no pacing): `--fast`, reports, tests."""
        frames = self.source.frames
        while self.position < len(frames):
            self.step()
            if progress and self.position % 5000 == 0:
                progress(self.position, len(frames))
        if progress:
            progress(len(frames), len(frames))
        self.finished.set()


# ---- gcs replay ------------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", help="a session folder, or a .tlog, DataFlash .bin or PX4 .ulg file")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument("--speed", type=float, default=1.0, help="playback speed (default 1 = real time)")
    pace.add_argument("--fast", action="store_true", help="as fast as possible")
    parser.add_argument("--estimator", "-e", action="append", metavar="NAME",
                        help="run only this estimator (repeatable; default all)")
    parser.add_argument("--gain", "-g", action="append", default=[], metavar="[EST.]NAME=VALUE",
                        help="override a gain (of EST, or of every selected estimator that has it)")


def parse_gains(items: list[str], names: list[str]) -> dict[str, dict[str, float]]:
    """`[EST.]NAME=VALUE` items → {estimator: {gain: value}}; ValueError says which item is wrong."""
    from gcs.estimators import registry

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
        targets = [est] if dot else [n for n in names if any(g.name == gain for g in registry.get(n).GAINS)]
        if not targets:
            raise ValueError(f"--gain {item!r}: no selected estimator ({', '.join(names)}) has a gain {gain!r}")
        for name in targets:
            out.setdefault(name, {})[gain] = value
    return out


def comparison_table(pipeline) -> list[str]:
    """Session RMS / max error per estimator per reference, degrees (roll, pitch, yaw)."""
    lines = [f"{'estimator':<10}{'reference':<10}{'n':>7}  {'RMS roll/pitch/yaw deg':<26}{'max roll/pitch/yaw deg'}"]
    for name, comparison in pipeline.comparisons.items():
        for ref, stats in comparison.summary()["references"].items():
            s = stats["session"]
            lines.append(f"{name:<10}{ref:<10}{s['n']:>7}  " + " ".join(f"{v:7.2f}" for v in s["rms"]) + "   "
                         + " ".join(f"{v:7.2f}" for v in s["max"]))
    return lines


def progress_bar(label: str) -> Callable[[int, int], None]:
    """A one-line progress bar on stderr for long runs."""
    def show(done: int, total: int) -> None:
        width = 30
        filled = int(width * done / max(total, 1))
        end = "\n" if done >= total else ""
        print(f"\r{label} [{'#' * filled}{'.' * (width - filled)}] {100 * done / max(total, 1):5.1f} %",
              end=end, file=sys.stderr, flush=True)
    return show


def run(args: argparse.Namespace) -> int:
    from gcs.estimators import registry
    from gcs.estimators.gains import GainError
    from gcs.sessions.readers import InputError
    from gcs.sessions.sources import open_source

    names = args.estimator or registry.names()
    try:
        for name in names:
            registry.get(name)
        gains = parse_gains(args.gain, names)
        source = open_source(args.path)
        session = ReplaySession(source, 0 if args.fast else args.speed, names, gains)
    except (InputError, KeyError, GainError, ValueError) as exc:
        print(f"gcs replay: error: {exc.args[0] if isinstance(exc, KeyError) else exc}", file=sys.stderr)
        return 2
    print(f"{source.kind} {source.path}: {len(source.frames)} frames, {source.duration:.1f} s, "
          f"{sum(source.counts.values())} messages/records", file=sys.stderr)
    started = time.perf_counter()
    if args.fast:
        session.run_to_end(progress_bar("replay"))
    else:
        asyncio.run(_paced(session))
    elapsed = time.perf_counter() - started
    print("\n".join(comparison_table(session.pipeline)))
    print(f"replayed {source.duration:.1f} s in {elapsed:.2f} s ({source.duration / max(elapsed, 1e-9):.1f}x real time); "
          f"{session.pipeline.imu_samples} IMU samples")
    if source.damage:
        print(f"damage: {source.damage}", file=sys.stderr)
    return 0


async def _paced(session: ReplaySession) -> None:
    task = asyncio.create_task(session.run())
    show = progress_bar("replay")
    try:
        while not session.finished.is_set():
            await asyncio.sleep(1.0)
            show(session.position, len(session.source.frames))
        show(len(session.source.frames), len(session.source.frames))
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
