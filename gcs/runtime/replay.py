"""Paced replay: a recorded session or a foreign log through the estimators on the event loop,
with play, pause, seek and speed.

`ReplaySession` is what the server drives: it has a `bus` (tlog packets are published there as
`Message`s stamped with their recorded wall time, so the dashboard shows them as it shows a live
link), an `add_listener(cb(points))` like `LiveEstimation`, and `play()`, `pause()`, `seek(t)`,
`set_speed(x)`, `status()`. Seeking rebuilds the estimators by re-running the inputs from the
start without pacing (they carry state, so there is no other exact way).
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable

from gcs.mavlink.framing import MavlinkDecoder
from gcs.runtime.bus import Message, MessageBus, vehicle_time_of
from gcs.sessions.sources import ReplaySource


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
                self.pipeline.feed(item)
            self.position += 1
        self._anchor = None
        if self.position < len(frames):
            self.finished.clear()

    def status(self) -> dict:
        frames = self.source.frames
        start = frames[0].t if frames else 0.0
        now = frames[min(self.position, len(frames) - 1)].t - start if frames else 0.0
        return {
            "path": self.source.path,
            "kind": self.source.kind,
            "position_s": round(now, 3),
            "duration_s": round(self.source.duration, 3),
            "frame": self.position,
            "frames": len(frames),
            "playing": self._playing.is_set() and not self.finished.is_set(),
            "finished": self.finished.is_set(),
            "speed": self.speed,
            "damage": self.source.damage,
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
                self.bus.publish(
                    Message(
                        msg,
                        msg.get_type(),
                        now,
                        frame.t,
                        vehicle_time_of(msg),
                        header.srcSystem,
                        header.srcComponent,
                        "replay",
                    )
                )
        points = []
        for item in frame.inputs:
            points += self.pipeline.feed(item)
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
