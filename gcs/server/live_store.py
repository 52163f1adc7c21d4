"""The live store: per source a preallocated ring of its last samples (`SeriesRing`), and what
`GET /api/history` makes of them (`history`): every sample, or min/max per plot column for a long
window, with the estimator errors computed as the page computes them, so a page opened now fills
its window at once and memory never grows."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from gcs.server import wire

#: The vehicle clock going back by more than this (s) in one source is a reboot (as gcs.runtime.boot_clock).
REBOOT_JUMP = 1.0
#: References an estimator's error history is computed against (as the page's error plots).
ERROR_REFERENCES = ("onboard", "truth")
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


def history(
    store: dict[str, SeriesRing],
    seconds: float,
    since: float | None = None,
    columns: int | None = None,
    estimators: tuple[str, ...] = (),
) -> HistorySlice:
    """The last `seconds` of vehicle time (or everything after `since`), per source and per
    estimator − reference error (`ERROR_REFERENCES`), columnar like a frame. With `columns`,
    a window holding more than two samples per column in any series is reduced to min and max
    per column (see `decimate`), so a 10-minute window costs what the plot can show."""
    newest = newest_time(store)
    if newest is None:
        return HistorySlice(seconds, 0.0, {}, {})
    t0 = newest - seconds if since is None else since
    raw = {source: ring.between(t0) for source, ring in store.items()}
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


def newest_time(store: dict[str, SeriesRing]) -> float | None:
    """The vehicle time of the newest sample of the current boot in any ring (None before the first)."""
    return max((ring.last_t() for ring in store.values() if ring.count), default=None)
