"""How late an estimator is behind ATTITUDE, kept incrementally.

The lag L minimises the mean of (roll error² + pitch error²) between the estimator at t + L and
ATTITUDE at t over the last `history` seconds, on a grid of L in ±lag_max. It used to be searched
from scratch (every L over every reference of the history) whenever a snapshot asked: 12–70 % of
the live station's CPU (issue 17). Here each reference, decimated to `spacing`, is scored once
for every L as soon as the estimator has passed t + lag_max, and the per-L sums are kept, so a
reference costs two interpolations of 2·lag_max/lag_step + 1 points once and `lag()` an argmin.
"""

from __future__ import annotations

import math
from collections import deque
from itertools import chain

import numpy as np
import numpy.typing as npt

from gcs.core.rotation import wrap_pi_array

Floats = npt.NDArray[np.float64]
#: Lags are taken when at least this many references cover them (as the search did).
MIN_POINTS = 10
#: Running sums are summed afresh after this many removals (rounding does not build up).
RESUM_EVERY = 4096


class RunningLag:
    def __init__(self, lag_max: float, lag_step: float, history: float, spacing: float) -> None:
        self.lag_step, self.lag_max, self.history, self.spacing = lag_step, lag_max, history, spacing
        steps = int(round(lag_max / lag_step))
        self.ks = list(range(-steps, steps + 1))
        self.offsets = np.array([k * lag_step for k in self.ks])
        self.estimates: deque[tuple[float, float, float]] = deque()  # (t, roll, pitch), lag_step apart
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

    def add_estimate(self, t: float, roll: float, pitch: float) -> None:
        """The estimator's roll and pitch at t (in time order; the caller keeps them lag_step apart)."""
        self.estimates.append((t, roll, pitch))
        while self.estimates[0][0] < t - self.history:
            self.estimates.popleft()
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
        est = self.estimates
        # the estimates around t ± lag_max (and one either side), from the newest back
        lo_t = t - self.lag_max - self.lag_step
        near = []
        for e in reversed(est):
            near.append(e)
            if e[0] < lo_t:
                break
        near.reverse()
        # the same array as np.array(near), in half the time (~100 tuples per reference)
        arr = np.fromiter(chain.from_iterable(near), np.float64, 3 * len(near)).reshape(-1, 3)
        ts = t + self.offsets
        covered = (ts >= est[0][0]) & (ts <= est[-1][0])
        dr = wrap_pi_array(np.interp(ts, arr[:, 0], arr[:, 1]) - roll)
        dp = np.interp(ts, arr[:, 0], arr[:, 2]) - pitch
        cost = np.where(covered, dr * dr + dp * dp, 0.0)
        weight = covered.astype(np.float64)
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
        enough = self.count >= MIN_POINTS
        if not enough.any():
            return None
        cost = np.where(enough, self.sum / np.maximum(self.count, 1.0), math.inf)
        return self.ks[int(np.argmin(cost))] * self.lag_step
