"""Live comparison of one ground-side estimator with the reference attitudes.

References (`AttitudeSample.source`): `onboard` (ATTITUDE), `ahrs2` (AHRS2) and `truth` (SIMSTATE), on the
vehicle clock (AHRS2 and SIMSTATE take the time of the previous timestamped message, see
`gcs.mavlink.sampling.VehicleClock`). A reference is scored once the estimator has passed its time, against
the estimator slerped between the two bracketing outputs: estimator − reference roll, pitch and wrapped yaw
in degrees, RMS and max |error| over the last `window` seconds and over the session. `lag()` is the delay
that best aligns roll and pitch with ATTITUDE. Below `min_imu_rate` (50 Hz) of raw IMU the comparison is
marked unreliable. Memory is bounded, and the numbers depend only on the samples fed, so a live run and an
offline recomputation over the same samples agree exactly.
Time alignment, lag, why 50 Hz: docs/estimators/comparison.md
"""

from __future__ import annotations

import math
from collections import deque
from typing import TypedDict

import numpy as np
import numpy.typing as npt

from gcs.core.rotation import quat_slerp, quat_to_euler, wrap_pi, wrap_pi_array
from gcs.core.samples import AttitudeSample

DEG = 180.0 / math.pi


class ErrorSummary(TypedDict):
    """RMS and max |error| (deg; roll, pitch, yaw) over n scored references."""

    n: int
    rms: list[float]
    max: list[float]


class ReferenceSummary(TypedDict):
    """`_Stats.summary()`: errors against one reference, over the window and the session."""

    n: int
    window: ErrorSummary
    session: ErrorSummary


class ComparisonSummary(TypedDict):
    """`Comparison.summary()`."""

    reliable: bool
    reason: str
    imu_rate: float
    lag: float | None
    dropped: int
    references: dict[str, ReferenceSummary]


class _Stats:
    """RMS and max |error| per axis (roll, pitch, yaw) over the session and a sliding window."""

    def __init__(self, window: float) -> None:
        self.window = window
        self.recent: deque[tuple[float, float, float, float]] = deque()
        self.n = 0
        self.sum_sq = [0.0, 0.0, 0.0]
        self.max = [0.0, 0.0, 0.0]

    def add(self, t: float, err: tuple[float, float, float]) -> None:
        self.recent.append((t, *err))
        while self.recent and self.recent[0][0] < t - self.window:
            self.recent.popleft()
        self.n += 1
        for i, e in enumerate(err):
            self.sum_sq[i] += e * e
            self.max[i] = max(self.max[i], abs(e))

    def summary(self) -> ReferenceSummary:
        w = list(self.recent)
        n = len(w)
        window_rms = [math.sqrt(sum(r[i] ** 2 for r in w) / n) if n else math.nan for i in (1, 2, 3)]
        window_max = [max(abs(r[i]) for r in w) if n else math.nan for i in (1, 2, 3)]
        session_rms = [math.sqrt(s / self.n) if self.n else math.nan for s in self.sum_sq]
        return {
            "n": self.n,
            "window": {"n": n, "rms": window_rms, "max": window_max},
            "session": {"n": self.n, "rms": session_rms, "max": list(self.max) if self.n else [math.nan] * 3},
        }


class Comparison:
    """Errors of one estimator's output against every reference source seen.

    Feed `add_estimate(t, q)` after each IMU update and `add_reference(sample)` for each
    reference, in arrival order; read `summary()` at any time.
    """

    def __init__(
        self,
        window: float = 10.0,
        history: float = 30.0,
        lag_max: float = 0.5,
        lag_step: float = 0.01,
        min_imu_rate: float = 50.0,
    ) -> None:
        self.window, self.history = window, history
        self.lag_max, self.lag_step, self.min_imu_rate = lag_max, lag_step, min_imu_rate
        self.estimates: deque[tuple[float, npt.NDArray[np.float64]]] = deque()
        self.pending: deque[AttitudeSample] = deque()
        self.onboard: deque[tuple[float, float, float]] = deque()  # (t, roll, pitch) for the lag search
        self.est_euler: deque[tuple[float, float, float]] = deque()
        self.stats: dict[str, _Stats] = {}
        self.dropped = 0

    def add_estimate(self, t: float, q: npt.NDArray[np.float64]) -> None:
        if self.estimates and t < self.estimates[-1][0]:  # vehicle clock went back: a new session
            self.estimates.clear()
            self.pending.clear()
            self.onboard.clear()
            self.est_euler.clear()
        if self.estimates and t == self.estimates[-1][0]:
            return
        self.estimates.append((t, np.array(q, dtype=float)))
        roll, pitch, _ = quat_to_euler(q)
        self.est_euler.append((t, roll, pitch))
        for buf in (self.estimates, self.est_euler):
            while buf[0][0] < t - self.history:
                buf.popleft()
        while self.pending and self.pending[0].t <= t:
            self._score(self.pending.popleft())

    def add_reference(self, ref: AttitudeSample) -> None:
        if self.estimates and ref.t <= self.estimates[-1][0]:
            self._score(ref)
        else:
            self.pending.append(ref)
            while self.pending[0].t < ref.t - self.history:
                self.pending.popleft()
                self.dropped += 1

    def _estimate_at(self, t: float) -> npt.NDArray[np.float64] | None:
        est = self.estimates
        if not est or t < est[0][0]:
            return None
        lo, hi = 0, len(est) - 1
        if t >= est[hi][0]:
            return est[hi][1]
        while hi - lo > 1:  # binary search for est[lo].t <= t < est[hi].t
            mid = (lo + hi) // 2
            if est[mid][0] <= t:
                lo = mid
            else:
                hi = mid
        (t0, q0), (t1, q1) = est[lo], est[hi]
        return quat_slerp(q0, q1, (t - t0) / (t1 - t0))

    def _score(self, ref: AttitudeSample) -> None:
        q = self._estimate_at(ref.t)
        if q is None:
            self.dropped += 1
            return
        roll, pitch, yaw = quat_to_euler(q)
        err = (wrap_pi(roll - ref.roll) * DEG, wrap_pi(pitch - ref.pitch) * DEG, wrap_pi(yaw - ref.yaw) * DEG)
        self.stats.setdefault(ref.source, _Stats(self.window)).add(ref.t, err)
        if ref.source == "onboard":
            self.onboard.append((ref.t, ref.roll, ref.pitch))
            while self.onboard[0][0] < ref.t - self.history:
                self.onboard.popleft()

    def imu_rate(self) -> float:
        """Estimator output (= raw IMU) rate over the last `window` seconds, Hz."""
        if len(self.estimates) < 2:
            return 0.0
        t_end = self.estimates[-1][0]
        times = [t for t, _ in self.estimates if t >= t_end - self.window]
        return (len(times) - 1) / (times[-1] - times[0]) if len(times) > 1 else 0.0

    def lag(self) -> float | None:
        """Best-aligning delay (s) of the estimator behind ATTITUDE, or None without overlap."""
        if len(self.onboard) < 10 or len(self.est_euler) < 2:
            return None
        est = np.array(self.est_euler)
        ref = np.array(self.onboard)
        steps = int(round(self.lag_max / self.lag_step))
        best, best_cost = None, math.inf
        for k in range(-steps, steps + 1):
            lag = k * self.lag_step
            ts = ref[:, 0] + lag
            inside = (ts >= est[0, 0]) & (ts <= est[-1, 0])
            if inside.sum() < 10:
                continue
            dr = np.interp(ts[inside], est[:, 0], est[:, 1]) - ref[inside, 1]
            dp = np.interp(ts[inside], est[:, 0], est[:, 2]) - ref[inside, 2]
            dr = wrap_pi_array(dr)
            cost = float(np.mean(dr * dr + dp * dp))
            if cost < best_cost:
                best, best_cost = lag, cost
        return best

    def reliability(self) -> tuple[bool, str]:
        rate = self.imu_rate()
        if rate < self.min_imu_rate:
            return False, (
                f"raw IMU at {rate:.1f} Hz < {self.min_imu_rate:g} Hz: a ground-side estimator cannot follow "
                f"the vehicle's motion; request RAW_IMU at 50 Hz or more"
            )
        return True, ""

    def summary(self) -> ComparisonSummary:
        reliable, reason = self.reliability()
        return {
            "reliable": reliable,
            "reason": reason,
            "imu_rate": self.imu_rate(),
            "lag": self.lag(),
            "dropped": self.dropped,
            "references": {source: s.summary() for source, s in sorted(self.stats.items())},
        }
