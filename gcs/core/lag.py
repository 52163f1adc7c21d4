"""How late an estimator is behind ATTITUDE, kept incrementally.

The lag L minimises the mean of (roll error² + pitch error²) between the estimator at t + L and
ATTITUDE at t over the last `history` seconds, on a grid of L in ±lag_max. It used to be searched
from scratch (every L over every reference of the history) whenever a snapshot asked: 12–70 % of
the live station's CPU (issue 17). Here each reference, decimated to `spacing`, is scored once
for every L as soon as the estimator has passed t + lag_max, and the per-L sums are kept, so a
reference costs two interpolations of 2·lag_max/lag_step + 1 points once and `lag()` an argmin.
The estimates are kept in arrays (`EstimateBuffer`) and a reference is scored by one compiled
call (`score_reference`: the same arithmetic as the NumPy it replaced, so the same sums), not by
a dozen small NumPy calls on an array built from tuples (~6-10 µs per reference instead of
~150-200 µs, in isolation).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np
import numpy.typing as npt

from gcs.core.estimators.jit import kernel

Floats = npt.NDArray[np.float64]
#: Lags are taken when at least this many references cover them (as the search did).
MIN_POINTS = 10
#: Running sums are summed afresh after this many removals (rounding does not build up).
RESUM_EVERY = 4096
#: rad: a lag is determined only where some lag tried fits this much worse (RMS) than the best
LAG_CONTRAST = math.radians(0.1)


@kernel
def score_reference(
    t: float, roll: float, pitch: float, est_t: Floats, est_roll: Floats, est_pitch: Floats,
    lag_max: float, lag_step: float, offsets: Floats, cost: Floats, weight: Floats,
) -> None:  # fmt: skip
    """One reference against the estimates at t + each offset: cost (roll error² + pitch error²,
    roll wrapped to [-π, π)) and weight (1 where the estimates cover t + offset, else both 0).
    The estimates interpolated are those from the last one before t - lag_max - lag_step on, as
    the NumPy version picked them."""
    lo_t = t - lag_max - lag_step
    j = len(est_t) - 1
    while j > 0 and not est_t[j] < lo_t:
        j -= 1
    ts = t + offsets
    r = np.interp(ts, est_t[j:], est_roll[j:])
    p = np.interp(ts, est_t[j:], est_pitch[j:])
    first, last = est_t[0], est_t[-1]
    for k in range(len(offsets)):
        if ts[k] >= first and ts[k] <= last:
            dr = (r[k] - roll + math.pi) % (2 * math.pi) - math.pi
            dp = p[k] - pitch
            cost[k] = dr * dr + dp * dp
            weight[k] = 1.0
        else:
            cost[k] = 0.0
            weight[k] = 0.0


class EstimateBuffer:
    """An estimator's (t, roll, pitch) over the lag's history, oldest first, in three arrays
    (`columns()`: contiguous views): appended at the end, dropped from the front."""

    def __init__(self, capacity: int = 1024) -> None:
        self._t, self._roll, self._pitch = np.empty(capacity), np.empty(capacity), np.empty(capacity)
        self._start = self._end = 0

    def __len__(self) -> int:
        return self._end - self._start

    def clear(self) -> None:
        self._start = self._end = 0

    def append(self, t: float, roll: float, pitch: float) -> None:
        end = self._end
        if end == len(self._t):  # full: move the live part to the front, or into arrays twice as long
            self._t, self._roll, self._pitch = (self._moved(a) for a in (self._t, self._roll, self._pitch))
            self._start, end = 0, len(self)
        self._t[end], self._roll[end], self._pitch[end] = t, roll, pitch
        self._end = end + 1

    def _moved(self, a: Floats) -> Floats:
        n = len(self)
        out = a if 2 * n <= len(a) else np.empty(2 * len(a))
        out[:n] = a[self._start : self._end]
        return out

    def drop_before(self, t: float) -> None:
        """Forget the estimates older than t."""
        times = self._t
        while times[self._start] < t:
            self._start += 1

    def columns(self) -> tuple[Floats, Floats, Floats]:
        live = slice(self._start, self._end)
        return self._t[live], self._roll[live], self._pitch[live]


class RunningLag:
    def __init__(self, lag_max: float, lag_step: float, history: float, spacing: float) -> None:
        self.lag_step, self.lag_max, self.history, self.spacing = lag_step, lag_max, history, spacing
        self.ks, self.offsets = lag_grid(lag_max, lag_step)
        self.estimates = EstimateBuffer()  # (t, roll, pitch), lag_step apart
        self.waiting: deque[tuple[float, float, float]] = deque()  # references not yet scorable
        self.reset()

    def reset(self) -> None:
        """Forget everything (the vehicle clock went back)."""
        self.estimates.clear()
        self.waiting.clear()
        self.scored: deque[tuple[float, Floats, Floats]] = deque()  # (t, cost per lag, covered per lag)
        self.sum = np.zeros(len(self.ks))
        self.count = np.zeros(len(self.ks))
        self._removed = 0
        self._last_ref = -math.inf
        self._last_estimate = -math.inf

    def last_estimate(self) -> float:
        """The time of the newest estimate kept (-inf before the first)."""
        return self._last_estimate

    def add_estimate(self, t: float, roll: float, pitch: float) -> None:
        """The estimator's roll and pitch at t (in time order; the caller keeps them lag_step apart)."""
        self.estimates.append(t, roll, pitch)
        self._last_estimate = t
        self.estimates.drop_before(t - self.history)
        while self.waiting and self.waiting[0][0] + self.lag_max <= t:
            self._score(*self.waiting.popleft())

    def add_reference(self, t: float, roll: float, pitch: float) -> None:
        """An ATTITUDE reference (in time order); one per `spacing` s is kept."""
        if t < self._last_ref + self.spacing:
            return
        self._last_ref = t
        self.waiting.append((t, roll, pitch))
        while self.waiting[0][0] < t - self.history:
            self.waiting.popleft()

    def _score(self, t: float, roll: float, pitch: float) -> None:
        cost, weight = np.empty(len(self.ks)), np.empty(len(self.ks))
        est_t, est_roll, est_pitch = self.estimates.columns()
        lag_max, lag_step = self.lag_max, self.lag_step
        score_reference(t, roll, pitch, est_t, est_roll, est_pitch, lag_max, lag_step, self.offsets, cost, weight)
        self.sum += cost
        self.count += weight
        self.scored.append((t, cost, weight))
        while self.scored[0][0] < t - self.history:
            _, c, w = self.scored.popleft()
            self.sum -= c
            self.count -= w
            self._removed += 1
        if self._removed >= RESUM_EVERY:
            self._removed = 0
            self.sum = np.sum([c for _, c, _ in self.scored], axis=0)
            self.count = np.sum([w for _, _, w in self.scored], axis=0)

    def lag(self) -> float | None:
        """The best lag on the grid (s; positive: the estimator is late), None without overlap."""
        return best_lag(self.sum, self.count, self.ks, self.lag_step)


def lag_grid(lag_max: float, lag_step: float) -> tuple[list[int], Floats]:
    """The lags tried: steps k of lag_step within ±lag_max, and k * lag_step (s)."""
    steps = int(round(lag_max / lag_step))
    ks = list(range(-steps, steps + 1))
    return ks, np.array([k * lag_step for k in ks])


def best_lag(cost_sum: Floats, count: Floats, ks: list[int], lag_step: float) -> float | None:
    """The lag of least mean cost among those covered by MIN_POINTS references; None where it is
    not determined: no lag covered, the least at either end of the lags covered (the lag may lie
    beyond them), or every lag within LAG_CONTRAST of the best (a vehicle at rest: its attitude
    hardly changes within the window, and the least is noise, often at ±lag_max)."""
    covered = np.flatnonzero(count >= MIN_POINTS)
    if not len(covered):
        return None
    cost = cost_sum[covered] / count[covered]
    best = int(np.argmin(cost))
    if best in (0, len(cost) - 1) or cost.max() - cost[best] < LAG_CONTRAST**2:
        return None
    return ks[int(covered[best])] * lag_step


def warm() -> None:
    """Compile (or load from the disk cache) the scoring kernel now, off the live loop."""
    lag = RunningLag(0.02, 0.01, 1.0, 0.0)
    for k in range(8):
        lag.add_estimate(0.01 * k, 0.0, 0.0)
        lag.add_reference(0.01 * k, 0.0, 0.0)
