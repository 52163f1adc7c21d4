"""Live comparison of one ground-side estimator with the reference attitudes.

References (`AttitudeSample.source`): `onboard` (ATTITUDE), `ahrs2` (AHRS2) and `truth` (SIMSTATE), on the
vehicle clock (AHRS2 and SIMSTATE take the time of their scheduler slot, see
`gcs.mavlink.sampling.VehicleClock`). A reference is scored once the estimator has passed its time, against
the estimator slerped between the two bracketing outputs: estimator − reference roll, pitch and yaw, each
wrapped to ±180°, in degrees (`errors_at`, the one error function: the live `Comparison`, what-if and the
report all use it), RMS and max |error| over the last `window` seconds and over the session. `lag()` is the
delay of the estimator behind ATTITUDE (positive: the estimator is late). Below
`RATE_TOLERANCE` × `min_imu_rate` (50 Hz) of raw IMU the comparison is marked unreliable. Memory is bounded,
and the numbers depend only on the samples fed, so a live run and an offline recomputation over the same
samples agree exactly.
Time alignment, lag, why 50 Hz: docs/estimators/comparison.md
"""

from __future__ import annotations

import math
from collections import deque
from typing import TypedDict

import numpy as np
import numpy.typing as npt

from gcs.core.rotation import quat_to_euler, wrap_pi_array
from gcs.core.samples import AttitudeSample

DEG = 180.0 / math.pi
#: A measured rate this close to the requested one counts as the requested one: over a 10 s window
#: one late or lost message (plus clock rounding) reads 50 Hz as ~49.9 Hz; 0.95 still flags a stream
#: really running slower (one group rate step below, 40 Hz, or heavy loss).
RATE_TOLERANCE = 0.95


def euler_array_to_quat(euler: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """N×3 Z-Y-X Euler angles (roll, pitch, yaw rad) → N×4 quaternions (w, x, y, z)."""
    hr, hp, hy = (euler[:, k] / 2 for k in range(3))
    cr, sr, cp, sp, cy, sy = np.cos(hr), np.sin(hr), np.cos(hp), np.sin(hp), np.cos(hy), np.sin(hy)
    return np.column_stack(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


def quat_array_to_euler(q: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """N×4 quaternions → N×3 Z-Y-X Euler angles (roll, pitch, yaw rad), as `quat_to_euler`."""
    w, x, y, z = (q[:, k] for k in range(4))
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - x * z), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.column_stack([roll, pitch, yaw])


def slerp_array(
    q0: npt.NDArray[np.float64], q1: npt.NDArray[np.float64], u: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """Row-wise `quat_slerp`: from q0 (u = 0) to q1 (u = 1) along the shorter arc."""
    d = np.sum(q0 * q1, axis=1)
    q1 = np.where((d < 0.0)[:, None], -q1, q1)
    d = np.abs(d)
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    s = np.sin(theta)
    near = d > 0.9995  # nearly equal: normalised linear interpolation is exact to rounding
    safe = np.where(near, 1.0, s)
    a = np.where(near, 1.0 - u, np.sin((1.0 - u) * theta) / safe)
    b = np.where(near, u, np.sin(u * theta) / safe)
    q = a[:, None] * q0 + b[:, None] * q1
    out: npt.NDArray[np.float64] = q / np.linalg.norm(q, axis=1)[:, None]
    return out


def errors_at(
    t: npt.NDArray[np.float64], q: npt.NDArray[np.float64], reference: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """Estimator − reference at the reference times inside the estimator's time span, degrees, as an
    M×4 array (t s, roll, pitch, yaw error). The one error function of the project.

    t (N, increasing) and q (N×4, w x y z) are the estimator's outputs; reference is M×4 (t s, roll,
    pitch, yaw rad). The estimator is slerped between the two outputs around each reference time
    (wrap-safe at roll ±180° and yaw ±180°, unlike interpolating angles), turned into Z-Y-X angles,
    and each difference is wrapped to ±180°. A reference before the first or after the last output
    is not scored.
    """
    if len(t) < 1 or len(reference) == 0:
        return np.empty((0, 4))
    inside = (reference[:, 0] >= t[0]) & (reference[:, 0] <= t[-1])
    ref = reference[inside]
    if len(t) == 1:
        est = np.repeat(q[:1], len(ref), axis=0)
    else:
        hi = np.clip(np.searchsorted(t, ref[:, 0], side="right"), 1, len(t) - 1)
        lo = hi - 1
        span = t[hi] - t[lo]
        u = np.clip((ref[:, 0] - t[lo]) / np.where(span > 0, span, 1.0), 0.0, 1.0)
        est = slerp_array(q[lo], q[hi], u)
    out = np.empty((len(ref), 4))
    out[:, 0] = ref[:, 0]
    out[:, 1:] = np.degrees(wrap_pi_array(quat_array_to_euler(est) - ref[:, 1:4]))
    return out


def errors_against(series: npt.NDArray[np.float64], reference: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """`errors_at` for an estimator given as an N×4 array (t s, roll, pitch, yaw rad), for reports
    and what-if, which keep angles: the angles are turned back into quaternions first."""
    if len(series) < 1:
        return np.empty((0, 4))
    return errors_at(series[:, 0], euler_array_to_quat(series[:, 1:4]), reference)


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

    def _bracket(self, t: float) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]] | None:
        """The outputs around t (times, quaternions), or None before the first."""
        est = self.estimates
        if not est or t < est[0][0]:
            return None
        lo, hi = 0, len(est) - 1
        if t >= est[hi][0]:
            return np.array([est[hi][0]]), est[hi][1][None, :]
        while hi - lo > 1:  # binary search for est[lo].t <= t < est[hi].t
            mid = (lo + hi) // 2
            if est[mid][0] <= t:
                lo = mid
            else:
                hi = mid
        return np.array([est[lo][0], est[hi][0]]), np.array([est[lo][1], est[hi][1]])

    def _score(self, ref: AttitudeSample) -> None:
        bracket = self._bracket(ref.t)
        if bracket is None:
            self.dropped += 1
            return
        row = errors_at(*bracket, np.array([[ref.t, ref.roll, ref.pitch, ref.yaw]]))
        err = (float(row[0, 1]), float(row[0, 2]), float(row[0, 3]))
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
        """How late the estimator is behind ATTITUDE, s: the shift L for which the estimator at t + L
        best matches ATTITUDE at t (roll and pitch). Positive: the estimator is behind (late);
        negative: ahead. None without overlap."""
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
        if rate < RATE_TOLERANCE * self.min_imu_rate:
            return False, (
                f"raw IMU at {rate:.1f} Hz, below the {self.min_imu_rate:g} Hz needed: a ground-side estimator "
                f"cannot follow the vehicle's motion; request RAW_IMU at {self.min_imu_rate:g} Hz or more"
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
