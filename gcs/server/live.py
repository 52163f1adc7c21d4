"""The live store and the WebSocket fan-out.

Every AttitudePoint (references and estimators) arrives through the `LiveEstimation.points` signal, in the
event loop, and goes to two places, both O(1) per point and never awaiting anyone:
* the **store**: per source a preallocated ring of the last `seconds × max_rate` samples, so a page
  opened now fills its window at once (`GET /api/history`) and memory never grows;
* the **pending frame**: flushed at most every `frame_interval` (10 ms), encoded to JSON once and
  offered to each client's own bounded queue (`ClientFeed`, `client_max_frames`), sent by the client's
  own task. A client that stops reading loses its oldest frames, counted for it alone; the others and
  the link never wait, and nothing is decimated for a client that keeps up.
Why 10 ms: docs/benchmarks.md; data flow: docs/design.md
"""

from __future__ import annotations

import asyncio
import itertools
import math
import time
from dataclasses import dataclass

import numpy as np

from gcs.core import strict_json
from gcs.core.estimation import AttitudePoint
from gcs.runtime.dropqueue import DropOldestQueue

DEG = 180.0 / math.pi


class SeriesRing:
    """The last `capacity` samples of one source: vehicle time (s, float64) and roll, pitch,
    yaw (degrees, float32), preallocated and touched at creation so its memory is fixed."""

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self.t = np.full(capacity, np.nan)
        self.rpy = np.full((capacity, 3), np.nan, dtype=np.float32)
        self.count = 0  # samples ever written

    def append(self, t: float, roll: float, pitch: float, yaw: float) -> None:
        i = self.count % self.capacity
        self.t[i] = t
        self.rpy[i] = (roll, pitch, yaw)
        self.count += 1

    def ordered(self) -> tuple[np.ndarray, np.ndarray]:
        """Times and angles, oldest first."""
        n = min(self.count, self.capacity)
        start = self.count % self.capacity if self.count > self.capacity else 0
        idx = (np.arange(n) + start) % self.capacity
        return self.t[idx], self.rpy[idx]

    def since(self, t0: float) -> tuple[np.ndarray, np.ndarray]:
        t, rpy = self.ordered()
        keep = t >= t0
        return t[keep], rpy[keep]


@dataclass(frozen=True, slots=True)
class ClientSnapshot:
    """One viewer's counters, as the status bar shows them."""

    id: int
    address: str
    sent_points: int
    sent_messages: int
    dropped_points: int
    dropped_frames: int
    queued_frames: int
    connected_s: float


@dataclass
class ClientFeed:
    """One WebSocket client's bounded queue of encoded frames and its counters."""

    id: int
    address: str
    max_frames: int

    def __post_init__(self) -> None:
        self.frames: DropOldestQueue[tuple[str, int]] = DropOldestQueue(self.max_frames)
        self.queued_points = 0
        self.sent_points = 0
        self.sent_messages = 0
        self.dropped_points = 0
        self.connected_at = time.monotonic()

    @property
    def dropped_frames(self) -> int:
        return self.frames.dropped

    def offer(self, text: str, points: int) -> None:
        """Queue a frame without waiting; when full, the oldest one is dropped and counted."""
        lost = self.frames.put((text, points))
        self.queued_points += points
        if lost is not None:
            self.queued_points -= lost[1]
            self.dropped_points += lost[1]

    async def next_message(self) -> tuple[str, int]:
        """Everything queued as one text message: a frame alone, or a "batch" of frames."""
        await self.frames.wait()
        frames = self.frames.drain()
        points = sum(n for _, n in frames)
        self.queued_points -= points
        text = (
            frames[0][0] if len(frames) == 1 else '{"type":"batch","frames":[' + ",".join(f for f, _ in frames) + "]}"
        )
        return text, points

    def sent(self, points: int) -> None:
        self.sent_points += points
        self.sent_messages += 1

    def snapshot(self) -> ClientSnapshot:
        return ClientSnapshot(
            id=self.id,
            address=self.address,
            sent_points=self.sent_points,
            sent_messages=self.sent_messages,
            dropped_points=self.dropped_points,
            dropped_frames=self.dropped_frames,
            queued_frames=len(self.frames),
            connected_s=round(time.monotonic() - self.connected_at, 1),
        )


class LiveHub:
    """Receives every AttitudePoint, keeps the live store and feeds the WebSocket clients."""

    def __init__(
        self,
        seconds: float = 600.0,
        max_rate: float = 400.0,
        frame_interval: float = 0.010,
        client_max_frames: int = 1000,
    ) -> None:
        self.capacity = int(seconds * max_rate)
        self.seconds = seconds
        self.frame_interval = frame_interval
        self.client_max_frames = client_max_frames
        self.store: dict[str, SeriesRing] = {}
        self.clients: dict[int, ClientFeed] = {}
        self.points_in = 0
        self.frames_out = 0
        self.last_arrival: float | None = None  # host monotonic s of the newest point
        self._pending: dict[str, list[list[float]]] = {}
        self._pending_n = 0
        self._last_flush = 0.0
        self._flush_handle: asyncio.Handle | None = None
        self._seq = itertools.count(1)
        self._ids = itertools.count(1)

    # ---- producers (event loop) ----------------------------------------------------------
    def on_points(self, points: list[AttitudePoint]) -> None:
        """LiveEstimation listener: store and queue every point; schedule a flush."""
        now = time.monotonic()
        self.last_arrival = now
        self.points_in += len(points)
        for p in points:
            roll, pitch, yaw = p.roll * DEG, p.pitch * DEG, p.yaw * DEG
            ring = self.store.get(p.source)
            if ring is None:
                ring = self.store[p.source] = SeriesRing(self.capacity)
            ring.append(p.t, roll, pitch, yaw)
            cols = self._pending.get(p.source)
            if cols is None:
                cols = self._pending[p.source] = [[], [], [], []]
            cols[0].append(round(p.t, 6))
            cols[1].append(round(roll, 3))
            cols[2].append(round(pitch, 3))
            cols[3].append(round(yaw, 3))
        self._pending_n += len(points)
        if self._flush_handle is None:
            loop = asyncio.get_running_loop()
            delay = self._last_flush + self.frame_interval - now
            self._flush_handle = loop.call_later(delay, self._flush) if delay > 0 else loop.call_soon(self._flush)

    def broadcast(self, message: dict) -> None:
        """A control message (gain change, ...) to every client, in order with the data."""
        if self._flush_handle is not None:
            self._flush_handle.cancel()
        self._flush()
        text = strict_json.dumps(message)
        for client in self.clients.values():
            client.offer(text, 0)

    def _flush(self) -> None:
        self._flush_handle = None
        if not self._pending_n:
            return
        self._last_flush = time.monotonic()
        text = strict_json.dumps(
            {"type": "points", "seq": next(self._seq), "server_time": self._last_flush, "points": self._pending},
            separators=(",", ":"),
        )
        n = self._pending_n
        self._pending, self._pending_n = {}, 0
        self.frames_out += 1
        for client in self.clients.values():
            client.offer(text, n)

    # ---- clients -------------------------------------------------------------------------
    def connect(self, address: str) -> ClientFeed:
        feed = ClientFeed(next(self._ids), address, self.client_max_frames)
        self.clients[feed.id] = feed
        return feed

    def disconnect(self, feed: ClientFeed) -> None:
        self.clients.pop(feed.id, None)

    # ---- readers -------------------------------------------------------------------------
    def data_age(self) -> float | None:
        """Seconds since the newest point arrived (None before the first)."""
        return None if self.last_arrival is None else time.monotonic() - self.last_arrival

    def history(self, seconds: float) -> dict[str, list[list[float]]]:
        """Per source, the samples of the last `seconds` of vehicle time, columnar like a frame."""
        newest = max(
            (ring.t[(ring.count - 1) % ring.capacity] for ring in self.store.values() if ring.count), default=None
        )
        if newest is None:
            return {}
        out = {}
        for source, ring in self.store.items():
            t, rpy = ring.since(newest - seconds)
            out[source] = [np.round(t, 6).tolist(), *(np.round(rpy[:, k].astype(float), 3).tolist() for k in range(3))]
        return out
