"""The live hub: every attitude into the live store and out to the WebSocket clients.

Every AttitudePoint (references and estimators) arrives through the `LiveEstimation.points` signal, in the
event loop, and goes to two places, both O(1) per point and never awaiting anyone:
* the **store** (`gcs.server.live_store`): per source a preallocated ring of the last
  `seconds × max_rate` samples, so a page opened now fills its window at once (`GET /api/history`)
  and memory never grows;
* the **pending frame**: flushed in the loop's next turn when the last flush is at least
  half a `flush_interval()` old (`FLUSH_GAP`), else when it will be; encoded once (binary float arrays,
  `gcs.server.wire`), the same bytes for every client, and written to each client in the
  flush's own turn (`gcs.server.client_feed`: no task woken per client per frame) unless a send to it is
  still waiting, when it joins that client's bounded queue (`client_max_frames`). Where the
  server offers it (`gcs.server.ws_direct`), the frame is also framed as a WebSocket message
  once, and those bytes go straight to each client's socket. A client that
  stops reading loses its oldest frames, counted for it alone; the others and the link never
  wait, and nothing is decimated for a client that keeps up.
Frames go out every `frame_interval` (15 ms, 67 frames/s: more than a 60 Hz page draws), however
many pages are open: the interval also paces the link's reads and the estimation's ticks, whose
turns cost more than the sends (shorter intervals for fewer pages made one page cost more than
five). Points that come sooner (a backlog's turns, back to back) wait for the gap, up to half an
interval, so frames then come at most twice per interval. The interval is the dial between CPU
and latency (figures for 5, 10 and 15 ms, and for one page at 4 ms: docs/benchmarks.md).
The live estimation's tick follows this interval (the dashboard paces it: `Station.pace_points`),
so its points come in one batch per interval and go out right after it. Figures:
docs/benchmarks.md; data flow: docs/design.md
"""

from __future__ import annotations

import asyncio
import itertools
import math
import operator
import time
from collections.abc import Callable
from itertools import groupby

from gcs.core.estimation import AttitudePoint
from gcs.server import wire
from gcs.server.client_feed import ClientFeed
from gcs.server.live_store import HistorySlice, SeriesRing, history, newest_time
from gcs.server.ws_direct import binary_frame

DEG = 180.0 / math.pi
_SOURCE = operator.attrgetter("source")
#: A frame goes out once this fraction of `flush_interval()` has passed since the last. The points
#: come paced by the interval already (the link's paced reads, or the estimation's tick), so the
#: hub's own gap only has to outlast a turn that comes a little early: waiting out the whole
#: interval set a timer (a wake-up of its own, and 0.2-8 ms more latency) for 2 frames in 3.
FLUSH_GAP = 0.5


class LiveHub:
    """Receives every AttitudePoint, keeps the live store and feeds the WebSocket clients."""

    def __init__(
        self,
        seconds: float = 600.0,
        max_rate: float = 400.0,
        frame_interval: float = 0.015,
        client_max_frames: int = 1000,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.capacity = int(seconds * max_rate)
        self.seconds = seconds
        self.frame_interval = frame_interval
        self.client_max_frames = client_max_frames
        #: host seconds for the flush gap and the data age (a test moves it by hand)
        self.clock = clock
        self.store: dict[str, SeriesRing] = {}
        self.clients: dict[int, ClientFeed] = {}
        self.points_in = 0
        self.frames_out = 0
        self.last_arrival: float | None = None  # `clock` s at the newest point
        self._pending: dict[str, list[list[float]]] = {}
        self._pending_n = 0
        self._last_flush = -math.inf  # none yet: the first points go out in the next turn
        self._flush_handle: asyncio.Handle | None = None
        self._seq = itertools.count(1)
        self._ids = itertools.count(1)

    # ---- producers (event loop) ----------------------------------------------------------
    def on_points(self, points: list[AttitudePoint]) -> None:
        """LiveEstimation listener: store and queue every point; schedule a flush. The points are
        taken per source as columns (sorted, grouped, zipped and converted by C loops), not one at
        a time: a served vehicle's turn brings ~30 of them at 1000 msg/s."""
        now = self.clock()
        self.last_arrival = now
        self.points_in += len(points)
        pending = self._pending
        for source, run in groupby(sorted(points, key=_SOURCE), key=_SOURCE):
            t, _, roll_rad, pitch_rad, yaw_rad = zip(*run, strict=True)
            to_deg = DEG.__mul__
            roll, pitch, yaw = list(map(to_deg, roll_rad)), list(map(to_deg, pitch_rad)), list(map(to_deg, yaw_rad))
            ring = self.store.get(source)
            if ring is None:
                ring = self.store[source] = SeriesRing(self.capacity)
            ring.extend(t, roll, pitch, yaw)
            cols = pending.get(source)
            if cols is None:
                cols = pending[source] = [[], [], [], []]
            cols[0] += t
            cols[1] += roll
            cols[2] += pitch
            cols[3] += yaw
        self._pending_n += len(points)
        if self._flush_handle is None:
            loop = asyncio.get_running_loop()
            delay = self._last_flush + FLUSH_GAP * self.flush_interval() - now
            self._flush_handle = loop.call_later(delay, self._flush) if delay > 0 else loop.call_soon(self._flush)

    def broadcast(self, message: dict) -> None:
        """A control message (gain change, ...) to every client, in order with the data."""
        if self._flush_handle is not None:
            self._flush_handle.cancel()
        self._flush()
        frame = wire.message_frame(message)
        framed = binary_frame(frame)
        for client in self.clients.values():
            client.offer(frame, 0, framed)

    def flush_interval(self) -> float:
        """Seconds between flushes (what the link's reads and the estimation's ticks follow)."""
        return self.frame_interval

    def _flush(self) -> None:
        self._flush_handle = None
        if not self._pending_n:
            return
        self._last_flush = self.clock()
        n = self._pending_n
        pending, self._pending, self._pending_n = self._pending, {}, 0
        if not self.clients:  # nobody to send it to (a page opening later reads the store)
            return
        frame = wire.points_frame(next(self._seq), self._last_flush, pending)
        framed = binary_frame(frame)  # once for every client
        self.frames_out += 1
        for client in self.clients.values():
            client.offer(frame, n, framed)

    # ---- clients -------------------------------------------------------------------------
    def connect(self, address: str) -> ClientFeed:
        feed = ClientFeed(next(self._ids), address, self.client_max_frames)
        self.clients[feed.id] = feed
        return feed

    def disconnect(self, feed: ClientFeed) -> None:
        self.clients.pop(feed.id, None)
        feed.close()

    # ---- readers -------------------------------------------------------------------------
    def data_age(self) -> float | None:
        """Seconds since the newest point arrived (None before the first)."""
        return None if self.last_arrival is None else self.clock() - self.last_arrival

    def newest(self) -> float | None:
        """The vehicle time of the newest sample of the current boot (None before the first)."""
        return newest_time(self.store)

    def history(
        self, seconds: float, since: float | None = None, columns: int | None = None, estimators: tuple[str, ...] = ()
    ) -> HistorySlice:
        """`live_store.history` of this hub's store."""
        return history(self.store, seconds, since, columns, estimators)
