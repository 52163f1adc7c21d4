"""How late an estimator is behind ATTITUDE, kept incrementally.

The lag L is fitted to the change of the error, not to the error: it minimises the mean of
(Δ roll error² + Δ pitch error²), Δ over `CHANGE_OVER` s, between the estimator at t + L and
ATTITUDE at t over the last `history` seconds, on a grid of L in ±lag_max. An offset that holds or
drifts slowly (dcm's roll in a turn, read off the centripetal acceleration) then cannot move it;
the mean squared error it minimised before traded such an offset for a slope of the attitude and
read dcm 0.25-0.38 s ahead of an ArduPlane in a turn (docs/estimators/comparison.md).
The lag used to be searched from scratch (every L over every reference of the history) whenever
a snapshot asked: 12–70 % of the live station's CPU (issue 17). Here each reference, decimated to
`spacing`, is scored once for every L as soon as the estimator has passed t + lag_max, against
the reference scored CHANGE_OVER before it, and the per-L sums are kept, so a reference costs two
interpolations of 2·lag_max/lag_step + 1 points once and `lag()` an argmin. The estimates are
kept in arrays (`EstimateBuffer`) and a reference is scored by one compiled call
(`score_reference`), not by a dozen small NumPy calls on an array built from tuples (~6-10 µs per
reference instead of ~150-200 µs, in isolation).
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
#: s: the error's change is taken from the newest reference at least this much older (none within
#: twice this, after a gap: the reference is not scored). Short against the time an offset takes to
#: change (a turn's: seconds), long against the samples' spacing, so a manoeuvre's change is seen.
CHANGE_OVER = 0.5
#: A scored reference's row: blocks of one value per lag, the roll and pitch errors (rad) and
#: whether the estimates cover the lag (1 or 0); then its score: the squared change of the error
#: since the reference CHANGE_OVER before, and whether both cover the lag (the blocks summed).
ROLL, PITCH, COVERED, SQUARES, PAIRED = range(5)
BLOCKS = 5
#: The blocks of a row that are summed: SQUARES and PAIRED.
SUMMED = 2


@kernel
def score_reference(
    t: float, roll: float, pitch: float, est_t: Floats, est_roll: Floats, est_pitch: Floats,
    lag_max: float, lag_step: float, offsets: Floats, row: Floats, before: Floats, paired: bool,
) -> None:  # fmt: skip
    """One reference against the estimates at t + each offset, into row's blocks (roll error
    wrapped to [-π, π)), all 0 where the estimates do not cover t + offset; scored against the
    row of the reference before (`paired`; unscored without one). The estimates interpolated
    are those from the last one before t - lag_max - lag_step on, as the NumPy version picked them."""
    lo_t = t - lag_max - lag_step
    j = len(est_t) - 1
    while j > 0 and not est_t[j] < lo_t:
        j -= 1
    ts = t + offsets
    r = np.interp(ts, est_t[j:], est_roll[j:])
    p = np.interp(ts, est_t[j:], est_pitch[j:])
    first, last = est_t[0], est_t[-1]
    n = len(offsets)
    for k in range(n):
        dr = dp = covered = squares = both = 0.0
        if ts[k] >= first and ts[k] <= last:
            dr = (r[k] - roll + math.pi) % (2 * math.pi) - math.pi
            dp = p[k] - pitch
            covered = 1.0
            if paired and before[COVERED * n + k] == 1.0:
                change_r = dr - before[ROLL * n + k]
                change_p = dp - before[PITCH * n + k]
                squares = change_r * change_r + change_p * change_p
                both = 1.0
        row[ROLL * n + k] = dr
        row[PITCH * n + k] = dp
        row[COVERED * n + k] = covered
        row[SQUARES * n + k] = squares
        row[PAIRED * n + k] = both


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
        self.scored: deque[tuple[float, Floats]] = deque()  # (t, its row: BLOCKS blocks of one value per lag)
        self.sums = np.zeros(SUMMED * len(self.ks))  # the rows' SQUARES and PAIRED, summed
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
        n = len(self.ks)
        row = np.empty(BLOCKS * n)
        before, paired = row, False
        for earlier, its_row in reversed(self.scored):  # the newest CHANGE_OVER before, a few back
            if earlier <= t - CHANGE_OVER:
                before, paired = its_row, earlier >= t - 2 * CHANGE_OVER
                break
        est_t, est_roll, est_pitch = self.estimates.columns()
        lag_max, lag_step, offsets = self.lag_max, self.lag_step, self.offsets
        score_reference(t, roll, pitch, est_t, est_roll, est_pitch, lag_max, lag_step, offsets, row, before, paired)
        self.sums += row[SQUARES * n :]
        self.scored.append((t, row))
        while self.scored[0][0] < t - self.history:
            self.sums -= self.scored.popleft()[1][SQUARES * n :]
            self._removed += 1
        if self._removed >= RESUM_EVERY:
            self._removed = 0
            self.sums = np.sum([r[SQUARES * n :] for _, r in self.scored], axis=0)

    def lag(self) -> float | None:
        """The best lag on the grid (s; positive: the estimator is late), None without overlap."""
        return best_lag(self.sums, self.ks, self.lag_step)


def lag_grid(lag_max: float, lag_step: float) -> tuple[list[int], Floats]:
    """The lags tried: steps k of lag_step within ±lag_max, and k * lag_step (s)."""
    steps = int(round(lag_max / lag_step))
    ks = list(range(-steps, steps + 1))
    return ks, np.array([k * lag_step for k in ks])


def best_lag(sums: Floats, ks: list[int], lag_step: float) -> float | None:
    """The lag of least mean squared change of the error among those covered by MIN_POINTS
    references, from the sums of the rows' SQUARES and PAIRED blocks; None where it is not
    determined: no lag covered, the least at either end of the lags covered (the lag may lie
    beyond them), or every lag within LAG_CONTRAST of the best (a vehicle at rest, or holding a
    steady turn: its attitude hardly changes within the window, and the least is noise, often at
    ±lag_max)."""
    squares, paired = sums.reshape(SUMMED, len(ks))
    covered = np.flatnonzero(paired >= MIN_POINTS)
    if not len(covered):
        return None
    cost = squares[covered] / paired[covered]
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
