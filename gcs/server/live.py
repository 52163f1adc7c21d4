"""The live store and the WebSocket fan-out.

Every AttitudePoint (references and estimators) arrives through the `LiveEstimation.points` signal, in the
event loop, and goes to two places, both O(1) per point and never awaiting anyone:
* the **store**: per source a preallocated ring of the last `seconds × max_rate` samples, so a page
  opened now fills its window at once (`GET /api/history`: every sample, or min/max per plot column
  for a long window, with the estimator errors computed as the page does) and memory never grows;
* the **pending frame**: flushed in the loop's next turn when the last flush is at least
  half a `flush_interval()` old (`FLUSH_GAP`), else when it will be; encoded once (binary float arrays,
  `gcs.server.wire`), the same bytes for every client, and written to each client in the
  flush's own turn (`ClientFeed`: no task woken per client per frame) unless a send to it is
  still waiting, when it joins that client's bounded queue (`client_max_frames`). Where the
  server offers it (`gcs.server.ws_direct`), the frame is also framed as a WebSocket message
  once, and those bytes go straight to each client's socket. A client that
  stops reading loses its oldest frames, counted for it alone; the others and the link never
  wait, and nothing is decimated for a client that keeps up.
The interval is the shortest that keeps the fan-out within `sends_per_s` (each send to each
client costs the loop ~26 µs of CPU, `bench.ws_fanout`, and every frame costs the live
estimation and the link a turn), between `frame_interval` and `max_frame_interval`: 4 ms for one
viewer, 6 for two, 3 ms more for each further one, 15 ms from 5 on (67 frames/s: more than a
60 Hz page draws). Points that come sooner (a backlog's turns, back to back) wait for the gap,
up to half an interval, so frames then come at most twice per interval; fewer viewers wait less.
The longest interval is the dial between CPU and latency: with 5 pages, 10 ms frames instead of
5 ms took `gcs serve` from 21.8 to 18.0 % of a core per 1000 msg/s, and 15 ms instead of 10 ms
from 19.4 to 16.5 % (medians of six alternating pairs), while the WebSocket p99 with 20 clients
under a CPU hog went from 11.6 to 17.1 ms, within the 20 ms the issue asks (docs/benchmarks.md).
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
from collections.abc import Callable, Coroutine, Sequence
from dataclasses import dataclass, fields
from itertools import groupby
from typing import Any

import numpy as np

from gcs.core.estimation import AttitudePoint
from gcs.runtime.dropqueue import DropOldestQueue
from gcs.server import eager, wire
from gcs.server.ws_direct import DirectWrite, binary_frame

DEG = 180.0 / math.pi
#: The vehicle clock going back by more than this (s) in one source is a reboot (as gcs.runtime.vehicle).
REBOOT_JUMP = 1.0
#: References an estimator's error history is computed against (as the page's error plots).
ERROR_REFERENCES = ("onboard", "truth")
_SOURCE = operator.attrgetter("source")
#: A frame goes out once this fraction of `flush_interval()` has passed since the last. The points
#: come paced by the interval already (the link's paced reads, or the estimation's tick), so the
#: hub's own gap only has to outlast a turn that comes a little early: waiting out the whole
#: interval set a timer (a wake-up of its own, and 0.2-8 ms more latency) for 2 frames in 3.
FLUSH_GAP = 0.5
#: A ring takes its gathered samples into its arrays once it holds this many.
SETTLE_EVERY = 256


class SeriesRing:
    """The last `capacity` samples of one source: vehicle time (s, float64) and roll, pitch,
    yaw (degrees, float32), preallocated and touched at creation so its memory is fixed.
    `boot_start` counts the samples written before the vehicle clock last went back by more
    than `REBOOT_JUMP` (a reboot): history serves only the current boot.

    New samples gather in plain lists (a few per source per turn of the loop: numpy's per-call
    cost would outweigh the copy) and go into the arrays every `SETTLE_EVERY` samples, or when
    something reads the ring."""

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self.t = np.full(capacity, np.nan)
        self.rpy = np.full((capacity, 3), np.nan, dtype=np.float32)
        self.count = 0  # samples ever written
        self.boot_start = 0
        self._last = -math.inf
        self._new: tuple[list[float], list[float], list[float], list[float]] = ([], [], [], [])

    def last_t(self) -> float:
        return self._last

    def extend(self, t: Sequence[float], roll: Sequence[float], pitch: Sequence[float], yaw: Sequence[float]) -> None:
        """Append samples, oldest first: times (s) and angles (degrees)."""
        if not t:
            return
        last = self._last
        if min(t) < max(last, max(t)) - REBOOT_JUMP:  # the clock may have gone back: find where
            for i, ti in enumerate(t):
                if ti < last - REBOOT_JUMP:
                    self.boot_start = self.count + i
                last = ti
        self._last = t[-1]
        new = self._new
        new[0].extend(t)
        new[1].extend(roll)
        new[2].extend(pitch)
        new[3].extend(yaw)
        self.count += len(t)
        if len(new[0]) >= SETTLE_EVERY:
            self._settle()

    def _settle(self) -> None:
        """The gathered samples into the arrays (only the newest `capacity` of them fit)."""
        t, roll, pitch, yaw = self._new
        if not t:
            return
        self._new = ([], [], [], [])
        n = min(len(t), self.capacity)
        i = (self.count - n) % self.capacity
        head = min(n, self.capacity - i)
        times, rpy = np.array(t[-n:]), np.array((roll[-n:], pitch[-n:], yaw[-n:])).T
        self.t[i : i + head], self.rpy[i : i + head] = times[:head], rpy[:head]
        self.t[: n - head], self.rpy[: n - head] = times[head:], rpy[head:]

    def ordered(self) -> tuple[np.ndarray, np.ndarray]:
        """Times and angles of the current boot, oldest first."""
        self._settle()
        first = max(self.boot_start, self.count - self.capacity)
        idx = np.arange(first, self.count) % self.capacity
        return self.t[idx], self.rpy[idx]

    def between(self, t0: float, t1: float = math.inf) -> tuple[np.ndarray, np.ndarray]:
        """Samples with t0 < t <= t1 (strictly after t0: `since` asks for what follows a known sample)."""
        t, rpy = self.ordered()
        keep = (t > t0) & (t <= t1)
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

    def as_dict(self) -> dict[str, int | float | str]:
        """The fields as JSON-ready values: every one is flat, so no `dataclasses.asdict` (its
        recursive copy cost each status request ~11 µs per viewer, 0.2 ms with 20)."""
        return {name: getattr(self, name) for name in CLIENT_FIELDS}


CLIENT_FIELDS = tuple(f.name for f in fields(ClientSnapshot))


#: How a feed writes one message to its client (the route's `WebSocket.send_bytes`).
Writer = Callable[[bytes], Coroutine[Any, Any, None]]


@dataclass
class ClientFeed:
    """One WebSocket client's encoded frames (`gcs.server.wire`) and its counters.

    Once it has a writer (the route attaches one), a frame offered while nothing is on its way
    to this client is written at once, in the flush's own turn: straight to the socket, already
    framed, where the server offers a direct write (`gcs.server.ws_direct`) and the socket takes
    it, else through the writer (`eager.start`: no task when the socket accepts it). While a
    send waits (a slow client: its transport paused), frames wait in the bounded queue, the
    oldest dropped and counted when it is full, and go out together as one message when the
    send is done; the flush, the link and the other clients never wait for it."""

    id: int
    address: str
    max_frames: int

    def __post_init__(self) -> None:
        self.writer: Writer | None = None
        self.direct: DirectWrite | None = None
        self.direct_writes = 0  # messages written straight to the socket (gcs.server.ws_direct)
        self.frames: DropOldestQueue[tuple[bytes, int]] = DropOldestQueue(self.max_frames)
        self.queued_points = 0
        self.sent_points = 0
        self.sent_messages = 0
        self.dropped_points = 0
        self.connected_at = time.monotonic()
        self.closed = False
        self._sending: asyncio.Task[None] | None = None

    @property
    def dropped_frames(self) -> int:
        return self.frames.dropped

    def offer(self, frame: bytes, points: int, framed: bytes | None = None) -> None:
        """Write a frame now if nothing is on its way to this client, else queue it without
        waiting; when the queue is full, the oldest frame is dropped and counted. `framed`: the
        frame as a whole WebSocket message (`ws_direct.binary_frame`), for a direct write."""
        if self.closed:
            return
        if self.writer is not None and self._sending is None and not self.frames:
            if self.direct is not None and self.direct(binary_frame(frame) if framed is None else framed):
                self.direct_writes += 1
                self.sent(points)
                return
            self._write(frame, points)
            return
        lost = self.frames.put((frame, points))
        self.queued_points += points
        if lost is not None:
            self.queued_points -= lost[1]
            self.dropped_points += lost[1]

    def attach(self, writer: Writer, direct: DirectWrite | None = None) -> None:
        """Start writing to the client: what was queued since it connected, then every frame;
        with `direct`, each frame straight to its socket whenever that takes it at once."""
        self.writer, self.direct = writer, direct
        if self.frames and self._sending is None and not self.closed:
            self._write(*self.take())

    def take(self) -> tuple[bytes, int]:
        """Everything queued as one binary message: its frames back to back (empty if none)."""
        frames = self.frames.drain()
        if len(frames) == 1:  # the usual case: a client that keeps up
            message, points = frames[0]
        else:
            message, points = b"".join(f for f, _ in frames), sum(n for _, n in frames)
        self.queued_points -= points
        return message, points

    def close(self) -> None:
        """Send nothing more (the client left, or a write to it failed)."""
        self.closed = True
        if self._sending is not None:
            self._sending.cancel()

    def _write(self, message: bytes, points: int) -> None:
        assert self.writer is not None
        try:
            task = eager.start(self.writer(message))
        except Exception:  # the client is gone: its route notices from its side and disconnects it
            self.close()
            return
        if task is None:
            self.sent(points)
            return
        self._sending = task
        task.add_done_callback(lambda done: self._written(done, points))

    def _written(self, task: asyncio.Task[None], points: int) -> None:
        self._sending = None
        if task.cancelled() or task.exception() is not None:
            self.close()
            return
        self.sent(points)
        if self.frames and not self.closed:
            self._write(*self.take())

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
        frame_interval: float = 0.004,
        client_max_frames: int = 1000,
        sends_per_s: float = 333.0,
        max_frame_interval: float = 0.015,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.capacity = int(seconds * max_rate)
        self.seconds = seconds
        self.frame_interval = frame_interval
        self.sends_per_s = sends_per_s
        self.max_frame_interval = max_frame_interval
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
        """Seconds between flushes: the fan-out within `sends_per_s`, between `frame_interval`
        and `max_frame_interval`."""
        return min(self.max_frame_interval, max(self.frame_interval, len(self.clients) / self.sends_per_s))

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
        return max((ring.last_t() for ring in self.store.values() if ring.count), default=None)

    def history(
        self, seconds: float, since: float | None = None, columns: int | None = None, estimators: tuple[str, ...] = ()
    ) -> HistorySlice:
        """The last `seconds` of vehicle time (or everything after `since`), per source and per
        estimator − reference error (`ERROR_REFERENCES`), columnar like a frame. With `columns`,
        a window holding more than two samples per column in any series is reduced to min and max
        per column (see `decimate`), so a 10-minute window costs what the plot can show."""
        newest = self.newest()
        if newest is None:
            return HistorySlice(seconds, 0.0, {}, {})
        t0 = newest - seconds if since is None else since
        raw = {source: ring.between(t0) for source, ring in self.store.items()}
        errors = {
            f"{est}|{ref}": error_series(raw[est], raw[ref])
            for est in estimators
            if est in raw
            for ref in ERROR_REFERENCES
            if ref in raw
        }
        series = {**raw, **errors}
        dt = 0.0
        if columns and any(len(t) > 2 * columns for t, _ in series.values()):
            dt = (newest - t0) / columns
            series = {name: decimate(t, rpy, dt) for name, (t, rpy) in series.items()}
        cols = {name: columnar(t, rpy) for name, (t, rpy) in series.items()}
        return HistorySlice(seconds, dt, {k: cols[k] for k in raw}, {k: cols[k] for k in errors})


@dataclass(frozen=True, slots=True)
class HistorySlice:
    """What GET /api/history answers: per source and per "estimator|reference" error
    [times, roll, pitch, yaw] (s, degrees), oldest first; `resolution_s` 0 for every sample,
    else the width of the min/max columns."""

    seconds: float
    resolution_s: float
    points: dict[str, list[list[float]]]
    errors: dict[str, list[list[float]]]


def columnar(t: np.ndarray, rpy: np.ndarray) -> list[list[float]]:
    """History columns; times rounded exactly as the live frames round them (wire.wire_times), so
    the page finds a sample it had live at the same time in the history (np.round can differ by
    an ulp, and the page then held the sample twice)."""
    return [wire.wire_times(t.tolist()), *(np.round(rpy[:, k].astype(float), 3).tolist() for k in range(3))]


def wrap180(d: np.ndarray) -> np.ndarray:
    return (d + 540.0) % 360.0 - 180.0


Columns = tuple[np.ndarray, np.ndarray]  # times (s) and [roll, pitch, yaw] (degrees)


def error_series(est: Columns, ref: Columns) -> Columns:
    """Estimator − reference at each reference time the estimator brackets, the estimator
    interpolated there along the shorter way round, each axis wrapped to ±180° (degrees): the
    page's own live rule (plots.js ErrorSeries), so history and live errors join without a seam."""
    te, ve = est
    tr, vr = ref
    if len(te) < 2 or not len(tr):
        return np.empty(0), np.empty((0, 3), dtype=np.float32)
    keep = (tr >= te[0]) & (tr <= te[-1])
    tr, vr = tr[keep], vr[keep].astype(float)
    k = np.clip(np.searchsorted(te, tr), 1, len(te) - 1)
    span = te[k] - te[k - 1]
    u = np.where(span > 0, (tr - te[k - 1]) / np.where(span > 0, span, 1.0), 1.0)[:, None]
    v0, v1 = ve[k - 1].astype(float), ve[k].astype(float)
    v = v0 + u * wrap180(v1 - v0)
    return tr, wrap180(v - vr).astype(np.float32)


def decimate(t: np.ndarray, rpy: np.ndarray, dt: float) -> Columns:
    """Min and max per axis in each column [c·dt, (c+1)·dt) of an absolute grid, in the order
    they happened, at the column's quarter and three-quarter times: the page's own drawing rule
    (plots.js Binner), so a one-sample spike survives any window. Every series shares the grid."""
    if not len(t):
        return t, rpy
    col = np.floor(t / dt).astype(np.int64)
    starts = np.flatnonzero(np.r_[True, col[1:] != col[:-1]])
    out = np.empty((2 * len(starts), 3), dtype=np.float32)
    for axis in range(3):
        v = rpy[:, axis]
        lo = np.minimum.reduceat(v, starts)
        hi = np.maximum.reduceat(v, starts)
        # which came first in each column: the index of the min vs the max
        i_lo = _arg_reduceat(v, starts, lo)
        i_hi = _arg_reduceat(v, starts, hi)
        first_min = i_lo <= i_hi
        out[0::2, axis] = np.where(first_min, lo, hi)
        out[1::2, axis] = np.where(first_min, hi, lo)
    cols = col[starts].astype(float)
    times = np.empty(2 * len(starts))
    times[0::2] = (cols + 0.25) * dt
    times[1::2] = (cols + 0.75) * dt
    return times, out


def _arg_reduceat(v: np.ndarray, starts: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Per segment, the first index where v equals that segment's target value."""
    seg = np.repeat(np.arange(len(starts)), np.diff(np.r_[starts, len(v)]))
    hit = np.flatnonzero(v == target[seg])
    first = np.full(len(starts), len(v))
    np.minimum.at(first, seg[hit], hit)
    return first
