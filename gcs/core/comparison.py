"""Live comparison of one ground-side estimator with the reference attitudes.

References (`AttitudeSample.source`): `onboard` (ATTITUDE), `ahrs2` (AHRS2) and `truth` (SIMSTATE), on the
vehicle clock (AHRS2 and SIMSTATE take the time of their scheduler slot, see
`gcs.mavlink.sampling.VehicleClock`). A reference is scored once the estimator has passed its time, against
the estimator slerped between the two bracketing outputs: estimator − reference roll, pitch and yaw, each
wrapped to ±180°, in degrees (`attitude_error`, the one error function: the live `Comparison`, and what-if
and the report through `errors_at`, all use it), RMS and max |error| over the last `window` seconds and
over the session. `lag()` is the delay of the estimator behind ATTITUDE (positive: the estimator is late). Below
`RATE_TOLERANCE` × `min_imu_rate` (50 Hz) of raw IMU the comparison is marked unreliable. Memory is bounded,
and the numbers depend only on the samples fed, so a live run and an offline recomputation over the same
samples agree exactly.
Time alignment, lag, why 50 Hz: docs/estimators/comparison.md
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from typing import TypedDict

import numpy as np
import numpy.typing as npt

from gcs.core import lag as running_lag
from gcs.core.estimators.kernels import attitude_error as compiled_attitude_error
from gcs.core.lag import RunningLag
from gcs.core.rotation import euler_quat, quat_slerp, quat_to_euler, wrap_pi
from gcs.core.samples import REBOOT_CLOCK_JUMP, AttitudeSample

DEG = 180.0 / math.pi
#: A measured rate this close to the requested one counts as the requested one: over a 10 s window
#: one late or lost message (plus clock rounding) reads 50 Hz as ~49.9 Hz; 0.95 still flags a stream
#: really running slower (one group rate step below, 40 Hz, or heavy loss).
RATE_TOLERANCE = 0.95
#: Hz of raw IMU a ground-side estimator needs to follow a vehicle's motion
MIN_IMU_RATE = 50.0


Quat = tuple[float, float, float, float]
#: A batch of inputs in arrival order, as runs: the IMU rows lo..hi, then a reference (None: none).
BatchRuns = list[tuple[int, int, AttitudeSample | None]]


def attitude_error(q0: Quat, q1: Quat, u: float, roll: float, pitch: float, yaw: float) -> tuple[float, float, float]:
    """The one error function: the estimator slerped from output q0 (u = 0) to q1 (u = 1) along
    the shorter arc, as Z-Y-X angles, minus the reference (rad), each difference wrapped to ±180°;
    degrees (roll, pitch, yaw). Slerp is wrap-safe where interpolating angles is not (roll near
    ±180° upside down, yaw through ±180°). Plain floats: the same numbers live and whole-run."""
    est_roll, est_pitch, est_yaw = quat_to_euler(quat_slerp(q0, q1, u))
    return (
        math.degrees(wrap_pi(est_roll - roll)),
        math.degrees(wrap_pi(est_pitch - pitch)),
        math.degrees(wrap_pi(est_yaw - yaw)),
    )


def errors_at(
    t: npt.NDArray[np.float64], q: npt.NDArray[np.float64], reference: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """`attitude_error` at every reference time inside the estimator's time span, as an M×4 array
    (t s, roll, pitch, yaw error deg), for whole runs (what-if, the report).

    t (N, increasing) and q (N×4, w x y z) are the estimator's outputs; reference is M×4 (t s, roll,
    pitch, yaw rad). Each reference is scored against the two outputs around it, as the live
    `Comparison` does; one before the first or after the last output is not scored.
    """
    if len(t) < 1 or len(reference) == 0:
        return np.empty((0, 4))
    inside = (reference[:, 0] >= t[0]) & (reference[:, 0] <= t[-1])
    ref = reference[inside]
    hi = np.minimum(np.searchsorted(t, ref[:, 0], side="right"), len(t) - 1)
    lo = np.maximum(hi - 1, 0)
    times, quats = t.tolist(), q.tolist()
    out = np.empty((len(ref), 4))
    for k, (rt, roll, pitch, yaw) in enumerate(ref.tolist()):
        i, j = int(lo[k]), int(hi[k])
        if rt >= times[-1]:
            i = j = len(times) - 1
        span = times[j] - times[i]
        u = (rt - times[i]) / span if span > 0 else 0.0
        out[k] = (rt, *attitude_error(quats[i], quats[j], u, roll, pitch, yaw))
    return out


def errors_against(series: npt.NDArray[np.float64], reference: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """`errors_at` for an estimator given as an N×4 array (t s, roll, pitch, yaw rad), for reports
    and what-if, which keep angles: the angles are turned back into quaternions first."""
    if len(series) < 1:
        return np.empty((0, 4))
    quats = np.array([euler_quat(r, p, y) for r, p, y in series[:, 1:4].tolist()])
    return errors_at(series[:, 0], quats, reference)


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


#: The window's running sums of squares are summed afresh after this many removals, so that
#: rounding from subtracting what leaves the window cannot build up over a long session.
RESUM_EVERY = 4096


class _Stats:
    """RMS and max |error| per axis (roll, pitch, yaw) over the session and a sliding window,
    kept as running sums (and, for the window's max, a monotonic queue per axis): a summary
    costs the same whatever the rates and the window."""

    def __init__(self, window: float) -> None:
        self.window = window
        self.recent: deque[tuple[float, float, float, float]] = deque()
        self.n = 0
        self.sum_sq = [0.0, 0.0, 0.0]
        self.max = [0.0, 0.0, 0.0]
        self.window_sum_sq = [0.0, 0.0, 0.0]
        self._removed = 0
        #: per axis (t, |e|) with |e| decreasing: the head is the window's max
        self.window_max: tuple[deque[tuple[float, float]], ...] = (deque(), deque(), deque())

    def add(self, t: float, err: tuple[float, float, float]) -> None:
        self.recent.append((t, *err))
        start = t - self.window
        wss = self.window_sum_sq
        while self.recent and self.recent[0][0] < start:
            _, a, b, c = self.recent.popleft()
            wss[0] -= a * a
            wss[1] -= b * b
            wss[2] -= c * c
            self._removed += 1
        if self._removed >= RESUM_EVERY:
            self._removed = 0
            for i in range(3):
                wss[i] = math.fsum(r[i + 1] * r[i + 1] for r in self.recent) - err[i] * err[i]
        self.n += 1
        sum_sq, top, window_max = self.sum_sq, self.max, self.window_max
        for i, e in enumerate(err):
            sq, mag = e * e, abs(e)
            sum_sq[i] += sq
            wss[i] += sq
            if mag > top[i]:  # = max(top[i], mag), NaN included
                top[i] = mag
            peaks = window_max[i]
            while peaks and peaks[-1][1] <= mag:
                peaks.pop()
            peaks.append((t, mag))
            while peaks[0][0] < start:
                peaks.popleft()

    def summary(self) -> ReferenceSummary:
        peaks = [queue[0][1] for queue in self.window_max] if self.recent else []
        return reference_summary(self.n, self.sum_sq, self.max, len(self.recent), self.window_sum_sq, peaks)


def reference_summary(
    n: int, sum_sq: Sequence[float], top: Sequence[float], window_n: int, window_sum_sq: Sequence[float],
    window_max: Sequence[float],
) -> ReferenceSummary:  # fmt: skip
    """The summary of running sums over n references (session) and window_n (window)."""
    if window_n:
        window_rms = [math.sqrt(max(v, 0.0) / window_n) for v in window_sum_sq]
        window_peaks = list(window_max)
    else:
        window_rms = window_peaks = [math.nan] * 3
    session_rms = [math.sqrt(s / n) if n else math.nan for s in sum_sq]
    return {
        "n": n,
        "window": {"n": window_n, "rms": window_rms, "max": window_peaks},
        "session": {"n": n, "rms": session_rms, "max": list(top) if n else [math.nan] * 3},
    }


#: Estimates `Comparison._bracket` steps back through before it bisects (a deque's middle is slow to reach).
SCAN_BACK = 32
#: References the lag keeps over its history at most (30 s of 50 Hz ATTITUDE is 1500; more add nothing).
LAG_POINTS = 500


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
        min_imu_rate: float = MIN_IMU_RATE,
    ) -> None:
        self.window, self.history = window, history
        self.lag_max, self.lag_step, self.min_imu_rate = lag_max, lag_step, min_imu_rate
        self.running_lag = RunningLag(lag_max, lag_step, history, history / LAG_POINTS)
        self.estimates: deque[tuple[float, Quat]] = deque()
        self.pending: deque[AttitudeSample] = deque()
        self.stats: dict[str, _Stats] = {}
        self.dropped = 0
        self._window_t: deque[float] = deque()  # estimate times of the last `window` s: the IMU rate

    def add_estimate(
        self, t: float, q: npt.NDArray[np.float64] | Sequence[float], euler: Sequence[float] | None = None
    ) -> None:
        """The estimator's output q (w, x, y, z) at t; `euler`, its Z-Y-X angles, when the caller has them."""
        self._add_estimates([t], [output_row(q, euler)], 0, 1)

    def add_batch(self, runs: BatchRuns, times: list[float], table: list[list[float]]) -> None:
        """A batch in arrival order (`BatchRuns`): `add_estimate` for each IMU row that gave an
        estimate (`table`: the estimator's outputs over the rows, stepping.BatchAttitudes' rows
        as lists; `times`, the rows'), `add_reference` for each reference."""
        for lo, hi, ref in runs:
            if hi > lo:
                self._add_estimates(times, table, lo, hi)
            if ref is not None:
                self.add_reference(ref)

    def _add_estimates(self, times: Sequence[float], table: Sequence[Sequence[float]], lo: int, hi: int) -> None:
        """Estimates lo..hi (the rows stepped), in time order: one loop with the attributes read
        once, as the live pipeline adds ~10 per tick per estimator."""
        estimates, recent, pending, lag = self.estimates, self._window_t, self.pending, self.running_lag
        history, window, lag_step = self.history, self.window, self.lag_step
        next_lag = lag.last_estimate() + lag_step
        for r in range(lo, hi):
            w, x, y, z, roll, pitch, _, _, stepped = table[r]
            if not stepped:
                continue
            t = times[r]
            if estimates:
                last = estimates[-1][0]
                if t < last:  # vehicle clock went back: a new session
                    self._restart()
                    next_lag = lag.last_estimate() + lag_step
                elif t == last:
                    continue
            estimates.append((t, (w, x, y, z)))
            if t >= next_lag:  # the lag's resolution
                lag.add_estimate(t, roll, pitch)
                next_lag = t + lag_step
            start = t - history
            while estimates[0][0] < start:
                estimates.popleft()
            recent.append(t)
            start = t - window
            while recent[0] < start:
                recent.popleft()
            while pending and pending[0].t <= t:
                self._score(pending.popleft())

    def _restart(self) -> None:
        """Start afresh on a vehicle clock that went back: what was kept of the old clock (the
        estimates, the references waiting for them, the lag's history, the rate's window) is not
        compared with the new; the session's figures go on."""
        self.estimates.clear()
        self.pending.clear()
        self.running_lag.reset()
        self._window_t.clear()

    def add_reference(self, ref: AttitudeSample) -> None:
        """A reference in arrival order. One more than REBOOT_CLOCK_JUMP behind the newest input is
        a new boot's (a rebooted vehicle's first ATTITUDE comes before its first IMU sample): the
        comparison restarts, as at the new boot's first estimate, rather than score it against the
        old boot's estimates at the same clock reading."""
        newest = max(
            self.estimates[-1][0] if self.estimates else -math.inf, self.pending[-1].t if self.pending else -math.inf
        )
        if ref.t < newest - REBOOT_CLOCK_JUMP:
            self._restart()
        if self.estimates and ref.t <= self.estimates[-1][0]:
            self._score(ref)
        else:
            self.pending.append(ref)
            while self.pending[0].t < ref.t - self.history:
                self.pending.popleft()
                self.dropped += 1

    def _score(self, ref: AttitudeSample) -> None:
        est = self.estimates
        if not est or ref.t < est[0][0]:
            self.dropped += 1
            return
        (t0, q0), (t1, q1) = self._bracket(ref.t)
        u = (ref.t - t0) / (t1 - t0) if t1 > t0 else 0.0
        err = compiled_attitude_error(q0, q1, u, ref.roll, ref.pitch, ref.yaw)
        stats = self.stats.get(ref.source)
        if stats is None:
            stats = self.stats[ref.source] = _Stats(self.window)
        stats.add(ref.t, err)
        if ref.source == "onboard":
            self.running_lag.add_reference(ref.t, ref.roll, ref.pitch)

    def _bracket(self, t: float) -> tuple[tuple[float, Quat], tuple[float, Quat]]:
        """The estimates at est[lo].t <= t < est[hi].t (both the last one when t is at or past it;
        est[0].t <= t). The times strictly increase, so the pair is unique: a reference is scored
        as soon as the estimator passes it, within a few estimates of the newest, so it is looked
        for from the newest back, and by bisection beyond `SCAN_BACK` of them."""
        est = self.estimates
        hi = len(est) - 1
        if t >= est[hi][0]:
            return est[hi], est[hi]
        newer = est[hi]
        for k, e in enumerate(reversed(est)):
            if e[0] <= t:
                return e, newer
            if k == SCAN_BACK:
                break
            newer = e
        lo = 0
        while hi - lo > 1:  # bisection for est[lo].t <= t < est[hi].t
            mid = (lo + hi) // 2
            if est[mid][0] <= t:
                lo = mid
            else:
                hi = mid
        return est[lo], est[hi]

    def imu_rate(self) -> float:
        """Estimator output (= raw IMU) rate over the last `window` seconds, Hz."""
        times = self._window_t
        return imu_rate_of(len(self.estimates), len(times), times[0] if times else 0.0, times[-1] if times else 0.0)

    def lag(self) -> float | None:
        """How late the estimator is behind ATTITUDE, s: the shift L for which the estimator at t + L
        best matches ATTITUDE at t (roll and pitch). Positive: the estimator is behind (late);
        negative: ahead. None without overlap. Kept as references arrive (gcs.core.lag): reading
        it costs an argmin."""
        return self.running_lag.lag()

    def reliability(self) -> tuple[bool, str]:
        return reliability(self.imu_rate(), self.min_imu_rate)

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


def output_row(q: npt.NDArray[np.float64] | Sequence[float], euler: Sequence[float] | None) -> list[float]:
    """An estimator's output q (w, x, y, z) and its Z-Y-X angles (from q without them) as a row
    of stepping.BatchAttitudes (valid and stepped)."""
    w, x, y, z = q.tolist() if isinstance(q, np.ndarray) else q
    quat = (float(w), float(x), float(y), float(z))
    roll, pitch, yaw = euler if euler is not None else quat_to_euler(quat)
    return [*quat, roll, pitch, yaw, 1.0, 1.0]


def imu_rate_of(estimates: int, times: int, first: float, last: float) -> float:
    """The rate of `times` estimate times from first to last, Hz (0 below two, or two estimates kept)."""
    if estimates < 2 or times < 2:
        return 0.0
    return (times - 1) / (last - first)


def reliability(rate: float, min_imu_rate: float) -> tuple[bool, str]:
    """Whether an estimator fed raw IMU at `rate` Hz can be compared, and why not."""
    if rate < RATE_TOLERANCE * min_imu_rate:
        return False, (
            f"raw IMU at {rate:.1f} Hz, below the {min_imu_rate:g} Hz needed: a ground-side estimator "
            f"cannot follow the vehicle's motion; request RAW_IMU at {min_imu_rate:g} Hz or more"
        )
    return True, ""


def warm() -> None:
    """Compile (or load from the disk cache) the comparison's kernels now, off the live loop."""
    running_lag.warm()
    compiled_attitude_error((1.0, 0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), 0.5, 0.0, 0.0, 0.0)
