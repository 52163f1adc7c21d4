"""The live comparison compiled: `Comparison`'s numbers from one compiled call per batch.

`gcs.core.comparison.Comparison` is the readable reference. The live estimation fed it per
sample from Python (the estimate's history, the pending references, the window's running sums and
monotonic queues, the decimated lag), about a quarter of the estimation's time in `gcs serve`
(issue 17). Here the same state lives in arrays and one kernel walks a batch's estimates and
references with the same arithmetic in the same order, so the summaries equal the reference's
(tests/test_comparison_compiled.py). Every queue is a linear buffer: lanes of rows, each lane with
its [start, end) bounds; a call that could overfill one is refused and the buffers are compacted
or grown first (`CompiledComparison._make_room`), so the kernel never allocates.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from gcs.core.comparison import (
    LAG_POINTS,
    MIN_IMU_RATE,
    RESUM_EVERY,
    BatchRuns,
    ComparisonSummary,
    imu_rate_of,
    output_row,
    reference_summary,
    reliability,
)
from gcs.core.estimators.jit import kernel
from gcs.core.estimators.kernels import attitude_error
from gcs.core.lag import BLOCKS, CHANGE_OVER, SQUARES, SUMMED, best_lag, lag_grid, score_reference
from gcs.core.samples import REBOOT_CLOCK_JUMP, AttitudeSample

Floats = npt.NDArray[np.float64]
Ints = npt.NDArray[np.int64]

#: params' slots
WINDOW, HISTORY, LAG_MAX, LAG_STEP, SPACING = range(5)
#: counts' slots: references dropped, the lag's removals since its last re-sum
DROPPED, LAG_REMOVED = range(2)
#: clock's slots: the lag's last reference kept and last estimate kept (-inf: none)
LAST_REF, LAST_LAG_ESTIMATE = range(2)
#: per source (lane) counts: references scored, removals from the window since the last re-sum
N, REMOVED = range(2)
#: per source sums: session sum of squares, session max |error|, window sum of squares (3 axes each)
SUM_SQ, TOP, WINDOW_SUM_SQ = 0, 3, 6
#: a buffer's bounds per lane
START, END = 0, 1
#: table columns (stepping.BatchAttitudes): quaternion, roll, pitch, stepped
Q, ROLL, PITCH, STEPPED = 0, 4, 5, 8


@kernel
def fsum(values: Floats) -> float:
    """math.fsum (CPython's algorithm: Shewchuk's partials, then the half-even fix-up), so the
    window's re-sum equals the reference's."""
    partials = np.empty(len(values) + 1)
    n = 0
    special = 0.0
    for k in range(len(values)):
        x = values[k]
        i = 0
        for j in range(n):
            y = partials[j]
            if abs(x) < abs(y):
                x, y = y, x
            hi = x + y
            lo = y - (hi - x)
            if lo != 0.0:
                partials[i] = lo
                i += 1
            x = hi
        n = i
        if x != 0.0:
            if not math.isfinite(x):  # a NaN or an infinity among the values (squares overflow never)
                special += values[k]
                n = 0
            else:
                partials[n] = x
                n += 1
    if special != 0.0:  # NaN too
        return special
    hi = 0.0
    lo = 0.0
    if n > 0:
        n -= 1
        hi = partials[n]
        while n > 0:
            x = hi
            n -= 1
            y = partials[n]
            hi = x + y
            lo = y - (hi - x)
            if lo != 0.0:
                break
        if n > 0 and ((lo < 0.0 and partials[n - 1] < 0.0) or (lo > 0.0 and partials[n - 1] > 0.0)):
            y = lo * 2.0
            x = hi + y
            if y == x - hi:
                hi = x
    return float(hi)


@kernel
def _push(bounds: Ints, lane: int) -> int:
    """The row of a new entry at the end of a lane."""
    end = int(bounds[lane, END])
    bounds[lane, END] = end + 1
    return end


@kernel
def _free(bounds: Ints, capacity: int) -> int:
    """Rows left at the end of the fullest lane."""
    return capacity - int(bounds[:, END].max())


@kernel
def _lag_score(
    p: Floats, counts: Ints, lag_est: Floats, lag_est_b: Ints, scored: Floats, scored_b: Ints, lag_sums: Floats,
    offsets: Floats, t: float, roll: float, pitch: float,
) -> None:  # fmt: skip
    """RunningLag._score: one waiting reference scored for every lag, into the running sums."""
    summed = 1 + SQUARES * len(offsets)  # the row's SQUARES and PAIRED blocks, after its time
    at = _push(scored_b, 0)
    row = scored[0, at]
    row[0] = t
    before, paired = at, False
    for r in range(at - 1, scored_b[0, START] - 1, -1):  # the newest CHANGE_OVER before, a few back
        if scored[0, r, 0] <= t - CHANGE_OVER:
            before, paired = r, scored[0, r, 0] >= t - 2 * CHANGE_OVER
            break
    live = lag_est[0, lag_est_b[0, START] : lag_est_b[0, END]]
    score_reference(
        t, roll, pitch, live[:, 0], live[:, 1], live[:, 2], p[LAG_MAX], p[LAG_STEP], offsets, row[1:],
        scored[0, before, 1:], paired,
    )  # fmt: skip
    lag_sums += row[summed:]
    start = t - p[HISTORY]
    while scored[0, scored_b[0, START], 0] < start:
        lag_sums -= scored[0, scored_b[0, START], summed:]
        scored_b[0, START] += 1
        counts[LAG_REMOVED] += 1
    if counts[LAG_REMOVED] >= RESUM_EVERY:
        counts[LAG_REMOVED] = 0
        lag_sums[:] = 0.0
        for r in range(scored_b[0, START], scored_b[0, END]):  # in order, as np.sum(axis=0) adds them
            lag_sums += scored[0, r, summed:]


@kernel
def _lag_add_estimate(
    p: Floats, counts: Ints, clock: Floats, lag_est: Floats, lag_est_b: Ints, waiting: Floats, waiting_b: Ints,
    scored: Floats, scored_b: Ints, lag_sums: Floats, offsets: Floats, t: float, roll: float, pitch: float,
) -> None:  # fmt: skip
    """RunningLag.add_estimate."""
    row = lag_est[0, _push(lag_est_b, 0)]
    row[0], row[1], row[2] = t, roll, pitch
    clock[LAST_LAG_ESTIMATE] = t
    start = t - p[HISTORY]
    while lag_est[0, lag_est_b[0, START], 0] < start:
        lag_est_b[0, START] += 1
    while waiting_b[0, START] < waiting_b[0, END] and waiting[0, waiting_b[0, START], 0] + p[LAG_MAX] <= t:
        ref = waiting[0, waiting_b[0, START]]
        waiting_b[0, START] += 1
        _lag_score(p, counts, lag_est, lag_est_b, scored, scored_b, lag_sums, offsets, ref[0], ref[1], ref[2])


@kernel
def _stats_add(
    p: Floats, recent: Floats, recent_b: Ints, peaks: Floats, peaks_b: Ints, src_counts: Ints, src_sums: Floats,
    s: int, t: float, err: tuple[float, float, float],
) -> None:  # fmt: skip
    """comparison._Stats.add for the source in lane s."""
    row = recent[s, _push(recent_b, s)]
    row[0], row[1], row[2], row[3] = t, err[0], err[1], err[2]
    start = t - p[WINDOW]
    sums = src_sums[s]
    while recent_b[s, START] < recent_b[s, END] and recent[s, recent_b[s, START], 0] < start:
        old = recent[s, recent_b[s, START]]
        a, b, c = old[1], old[2], old[3]
        sums[WINDOW_SUM_SQ] -= a * a
        sums[WINDOW_SUM_SQ + 1] -= b * b
        sums[WINDOW_SUM_SQ + 2] -= c * c
        recent_b[s, START] += 1
        src_counts[s, REMOVED] += 1
    if src_counts[s, REMOVED] >= RESUM_EVERY:
        src_counts[s, REMOVED] = 0
        live = recent[s, recent_b[s, START] : recent_b[s, END]]
        for i in range(3):
            sums[WINDOW_SUM_SQ + i] = fsum(live[:, i + 1] * live[:, i + 1]) - err[i] * err[i]
    src_counts[s, N] += 1
    for i in range(3):
        e = err[i]
        sq, mag = e * e, abs(e)
        sums[SUM_SQ + i] += sq
        sums[WINDOW_SUM_SQ + i] += sq
        if mag > sums[TOP + i]:
            sums[TOP + i] = mag
        lane = 3 * s + i
        while peaks_b[lane, END] > peaks_b[lane, START] and peaks[lane, peaks_b[lane, END] - 1, 1] <= mag:
            peaks_b[lane, END] -= 1
        peak = peaks[lane, _push(peaks_b, lane)]
        peak[0], peak[1] = t, mag
        while peaks[lane, peaks_b[lane, START], 0] < start:
            peaks_b[lane, START] += 1


@kernel
def _score(
    p: Floats, counts: Ints, clock: Floats, est: Floats, est_b: Ints, recent: Floats, recent_b: Ints,
    peaks: Floats, peaks_b: Ints, src_counts: Ints, src_sums: Floats, waiting: Floats, waiting_b: Ints,
    ref: Floats, onboard: int,
) -> None:  # fmt: skip
    """Comparison._score: the reference against the estimator slerped between its two outputs
    around it (est[lo].t <= t < est[hi].t; the newest twice at or past it)."""
    t = ref[0]
    lo, hi = est_b[0, START], est_b[0, END] - 1
    if hi < lo or t < est[0, lo, 0]:
        counts[DROPPED] += 1
        return
    if t >= est[0, hi, 0]:
        lo = hi
    else:
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if est[0, mid, 0] <= t:
                lo = mid
            else:
                hi = mid
    a, b = est[0, lo], est[0, hi]
    u = (t - a[0]) / (b[0] - a[0]) if b[0] > a[0] else 0.0
    err = attitude_error((a[1], a[2], a[3], a[4]), (b[1], b[2], b[3], b[4]), u, ref[1], ref[2], ref[3])
    s = int(ref[4])
    _stats_add(p, recent, recent_b, peaks, peaks_b, src_counts, src_sums, s, t, err)
    if s == onboard and not t < clock[LAST_REF] + p[SPACING]:  # RunningLag.add_reference
        clock[LAST_REF] = t
        row = waiting[0, _push(waiting_b, 0)]
        row[0], row[1], row[2] = t, ref[1], ref[2]
        while waiting[0, waiting_b[0, START], 0] < t - p[HISTORY]:
            waiting_b[0, START] += 1


@kernel
def _restart(
    counts: Ints, clock: Floats, est_b: Ints, times_b: Ints, pending_b: Ints, lag_est_b: Ints, waiting_b: Ints,
    scored_b: Ints, lag_sums: Floats,
) -> None:  # fmt: skip
    """Comparison._restart: the buffers of the old clock emptied, the lag's sums zeroed."""
    est_b[0, :] = 0
    times_b[0, :] = 0
    pending_b[0, :] = 0
    lag_est_b[0, :] = 0
    waiting_b[0, :] = 0
    scored_b[0, :] = 0
    lag_sums[:] = 0.0
    counts[LAG_REMOVED] = 0
    clock[LAST_REF] = clock[LAST_LAG_ESTIMATE] = -math.inf


@kernel
def add_batch(
    p: Floats, counts: Ints, clock: Floats, est: Floats, est_b: Ints, times_b: Ints, pending: Floats,
    pending_b: Ints, recent: Floats, recent_b: Ints, peaks: Floats, peaks_b: Ints, src_counts: Ints,
    src_sums: Floats, lag_est: Floats, lag_est_b: Ints, waiting: Floats, waiting_b: Ints, scored: Floats,
    scored_b: Ints, lag_sums: Floats, offsets: Floats, onboard: int, imu: Floats, table: Floats,
    refs: Floats, ends: Ints,
) -> bool:  # fmt: skip
    """Comparison.add_batch over the rows' outputs (`table`, at the times in `imu`'s first
    column: stepping.ImuBatch.rows) and the references
    (`refs`: t, roll, pitch, yaw, source lane; refs[k] arrives after the rows before ends[k]).
    False, with nothing done, when a buffer could fill or a source has no lane yet.

    `times_b` bounds the estimate times of the last `window` s (the IMU rate) within est's rows,
    which the history keeps (window <= history, checked at construction)."""
    n, m = len(table), len(refs)
    waiting_n, pending_n = waiting_b[0, END] - waiting_b[0, START], pending_b[0, END] - pending_b[0, START]
    scorable = pending_n + m
    if (
        _free(est_b, est.shape[1]) < n
        or _free(lag_est_b, lag_est.shape[1]) < n
        or _free(pending_b, pending.shape[1]) < m
        or _free(recent_b, recent.shape[1]) < scorable
        or _free(peaks_b, peaks.shape[1]) < scorable
        or _free(waiting_b, waiting.shape[1]) < scorable
        or _free(scored_b, scored.shape[1]) < waiting_n + scorable
        or (m > 0 and refs[:, 4].max() >= recent.shape[0])
    ):
        return False
    history, window = p[HISTORY], p[WINDOW]
    first = 0
    for k in range(m + 1):
        stop = ends[k] if k < m else n
        for r in range(first, stop):  # Comparison._add_estimates
            out = table[r]
            if out[STEPPED] == 0.0:
                continue
            t = imu[r, 0]
            if est_b[0, END] > est_b[0, START]:
                last = est[0, est_b[0, END] - 1, 0]
                if t < last:  # vehicle clock went back: a new session
                    _restart(counts, clock, est_b, times_b, pending_b, lag_est_b, waiting_b, scored_b, lag_sums)
                elif t == last:
                    continue
            row = est[0, _push(est_b, 0)]
            row[0], row[1], row[2], row[3], row[4] = t, out[Q], out[Q + 1], out[Q + 2], out[Q + 3]
            times_b[0, END] = est_b[0, END]
            if t >= clock[LAST_LAG_ESTIMATE] + p[LAG_STEP]:  # the lag's resolution
                _lag_add_estimate(
                    p, counts, clock, lag_est, lag_est_b, waiting, waiting_b, scored, scored_b, lag_sums, offsets, t,
                    out[ROLL], out[PITCH],
                )  # fmt: skip
            start = t - history
            while est[0, est_b[0, START], 0] < start:
                est_b[0, START] += 1
            times_b[0, START] = max(times_b[0, START], est_b[0, START])
            start = t - window
            while est[0, times_b[0, START], 0] < start:
                times_b[0, START] += 1
            while pending_b[0, START] < pending_b[0, END] and pending[0, pending_b[0, START], 0] <= t:
                ref = pending[0, pending_b[0, START]]
                pending_b[0, START] += 1
                _score(
                    p, counts, clock, est, est_b, recent, recent_b, peaks, peaks_b, src_counts, src_sums, waiting,
                    waiting_b, ref, onboard,
                )  # fmt: skip
        first = stop
        if k < m:  # Comparison.add_reference
            ref = refs[k]
            newest = -math.inf
            if est_b[0, END] > est_b[0, START]:
                newest = est[0, est_b[0, END] - 1, 0]
            if pending_b[0, END] > pending_b[0, START]:
                newest = max(newest, pending[0, pending_b[0, END] - 1, 0])
            if ref[0] < newest - REBOOT_CLOCK_JUMP:  # a new boot's reference before its first estimate
                _restart(counts, clock, est_b, times_b, pending_b, lag_est_b, waiting_b, scored_b, lag_sums)
            if est_b[0, END] > est_b[0, START] and ref[0] <= est[0, est_b[0, END] - 1, 0]:
                _score(
                    p, counts, clock, est, est_b, recent, recent_b, peaks, peaks_b, src_counts, src_sums, waiting,
                    waiting_b, ref, onboard,
                )  # fmt: skip
            else:
                pending[0, _push(pending_b, 0)] = ref
                while pending[0, pending_b[0, START], 0] < ref[0] - history:
                    pending_b[0, START] += 1
                    counts[DROPPED] += 1
    return True


#: the kernel, called with its state unpacked (`CompiledComparison._arrays`)
_add_batch: Callable[..., bool] = add_batch


class _Buffer:
    """Lanes of rows (lanes × capacity × width) and their [start, end) bounds."""

    def __init__(self, lanes: int, width: int, capacity: int = 256) -> None:
        self.rows = np.empty((lanes, capacity, width))
        self.bounds = np.zeros((lanes, 2), dtype=np.int64)

    def make_room(self, need: int, lanes: int = 0) -> None:
        """Room for `need` more rows after every lane's end, and `lanes` lanes at least: the live
        rows moved to the front, into arrays at least twice as long as the live rows and the need
        (so that moves stay rare) when they do not fit."""
        live = int((self.bounds[:, END] - self.bounds[:, START]).max())
        capacity = self.rows.shape[1]
        if capacity - int(self.bounds[:, END].max()) >= need and lanes <= len(self.rows):
            return
        rows = self.rows
        if live + need > capacity // 2 or lanes > len(rows):
            capacity = max(capacity, 2 * (live + need))
            rows = np.empty((max(lanes, len(self.rows)), capacity, self.rows.shape[2]))
        for lane, (start, end) in enumerate(self.bounds.tolist()):
            rows[lane, : end - start] = self.rows[lane, start:end]  # numpy copies an overlap first
        more = len(rows) - len(self.bounds)
        self.rows = rows
        self.bounds = np.vstack([self.bounds - self.bounds[:, :1], np.zeros((more, 2), np.int64)])


#: lanes of the per-source buffers: one per source name, the same for every comparison
SOURCES: dict[str, int] = {}


def source_lane(name: str) -> int:
    """The lane of a reference source (interned on first sight: the few names of the references)."""
    return SOURCES.setdefault(name, len(SOURCES))


@dataclass(frozen=True, slots=True)
class ReferenceRuns:
    """A batch's runs (`BatchRuns`) with their references as the kernel takes them, built once per
    batch for every comparison: refs (t, roll, pitch, yaw, source lane) and, for each, the IMU
    rows that arrived before it."""

    runs: BatchRuns
    refs: Floats
    ends: Ints

    @classmethod
    def of(cls, runs: BatchRuns) -> ReferenceRuns:
        if len(runs) == 1 and runs[0][2] is None:  # no reference
            return cls(runs, NO_REFERENCES.refs, NO_REFERENCES.ends)
        refs = [(r.t, r.roll, r.pitch, r.yaw, float(source_lane(r.source))) for _, _, r in runs if r is not None]
        ends = [hi for _, hi, r in runs if r is not None]
        return cls(runs, np.array(refs, dtype=np.float64).reshape(-1, 5), np.array(ends, dtype=np.int64))


#: no IMU rows (add_reference): their times and outputs
NO_ROWS, NO_OUTPUTS = np.empty((0, 1)), np.empty((0, 9))
NO_REFERENCES = ReferenceRuns([], np.empty((0, 5)), np.empty(0, dtype=np.int64))


class CompiledComparison:
    """`Comparison` (the same constructor, inputs and summary) on the compiled kernel."""

    def __init__(
        self,
        window: float = 10.0,
        history: float = 30.0,
        lag_max: float = 0.5,
        lag_step: float = 0.01,
        min_imu_rate: float = MIN_IMU_RATE,
    ) -> None:
        if window > history:
            raise ValueError(f"window {window} s longer than the history {history} s")
        self.window, self.history, self.min_imu_rate = window, history, min_imu_rate
        self.lag_step = lag_step
        self.ks, self.offsets = lag_grid(lag_max, lag_step)
        self.params = np.array([window, history, lag_max, lag_step, history / LAG_POINTS])
        self.counts = np.zeros(2, dtype=np.int64)
        self.clock = np.full(2, -math.inf)
        self.est = _Buffer(1, 5)  # t, w, x, y, z over the history
        self.times_b = np.zeros((1, 2), dtype=np.int64)  # est's rows of the last window s
        self.pending = _Buffer(1, 5)  # t, roll, pitch, yaw, source lane
        sources = max(len(SOURCES), 1)
        self.recent = _Buffer(sources, 4)  # per source: t, roll, pitch, yaw error over the window
        self.peaks = _Buffer(3 * sources, 2)  # per source and axis: (t, |error|), |error| decreasing
        self.src_counts = np.zeros((sources, 2), dtype=np.int64)
        self.src_sums = np.zeros((sources, 9))
        self.lag_est = _Buffer(1, 3)  # t, roll, pitch, lag_step apart
        self.waiting = _Buffer(1, 3)  # references the lag cannot score yet
        self.scored = _Buffer(1, 1 + BLOCKS * len(self.ks), 64)  # t, RunningLag's row
        self.lag_sums = np.zeros(SUMMED * len(self.ks))  # the rows' SQUARES and PAIRED, summed over scored
        self._state = self._arrays()

    @property
    def dropped(self) -> int:
        return int(self.counts[DROPPED])

    def add_estimate(
        self, t: float, q: npt.NDArray[np.float64] | Sequence[float], euler: Sequence[float] | None = None
    ) -> None:
        """The estimator's output q (w, x, y, z) at t; `euler`, its Z-Y-X angles, when the caller has them."""
        self.add_batch(NO_REFERENCES, np.array([[t]]), np.array([output_row(q, euler)]))

    def add_reference(self, ref: AttitudeSample) -> None:
        self.add_batch(ReferenceRuns.of([(0, 0, ref)]), NO_ROWS, NO_OUTPUTS)

    def add_batch(self, runs: ReferenceRuns, imu: Floats, table: Floats) -> None:
        """`Comparison.add_batch`: the IMU rows' outputs (`table`, stepping.BatchAttitudes.rows) at
        the times in the first column of `imu` (stepping.ImuBatch.rows), with the references."""
        while not _add_batch(*self._state, SOURCES.get("onboard", -1), imu, table, runs.refs, runs.ends):
            self._make_room(len(table), len(runs.refs))
            self._state = self._arrays()

    def _arrays(self) -> tuple[Any, ...]:
        """The kernel's state arguments, in its order (new arrays only after `_make_room`)."""
        return (
            self.params, self.counts, self.clock, self.est.rows, self.est.bounds, self.times_b, self.pending.rows,
            self.pending.bounds, self.recent.rows, self.recent.bounds, self.peaks.rows, self.peaks.bounds,
            self.src_counts, self.src_sums, self.lag_est.rows, self.lag_est.bounds, self.waiting.rows,
            self.waiting.bounds, self.scored.rows, self.scored.bounds, self.lag_sums, self.offsets,
        )  # fmt: skip

    def _make_room(self, n: int, m: int) -> None:
        """Room for n estimates and m references in every buffer, a lane for every source."""
        pending = int(self.pending.bounds[0, END] - self.pending.bounds[0, START])
        waiting = int(self.waiting.bounds[0, END] - self.waiting.bounds[0, START])
        moved_from = int(self.est.bounds[0, START])
        self.est.make_room(n)
        self.times_b -= moved_from - int(self.est.bounds[0, START])  # the window's times moved with est
        self.lag_est.make_room(n)
        self.pending.make_room(m)
        sources = len(SOURCES)
        self.recent.make_room(pending + m, sources)
        self.peaks.make_room(pending + m, 3 * sources)
        self.waiting.make_room(pending + m)
        self.scored.make_room(waiting + pending + m)
        more = sources - len(self.src_counts)
        if more > 0:
            self.src_counts = np.vstack([self.src_counts, np.zeros((more, 2), np.int64)])
            self.src_sums = np.vstack([self.src_sums, np.zeros((more, 9))])

    def imu_rate(self) -> float:
        """Estimator output (= raw IMU) rate over the last `window` seconds, Hz."""
        start, end = self.times_b[0].tolist()
        est_start, est_end = self.est.bounds[0].tolist()
        first, last = (self.est.rows[0, start, 0], self.est.rows[0, end - 1, 0]) if end > start else (0.0, 0.0)
        return imu_rate_of(est_end - est_start, end - start, float(first), float(last))

    def lag(self) -> float | None:
        """Comparison.lag."""
        return best_lag(self.lag_sums, self.ks, self.lag_step)

    def reliability(self) -> tuple[bool, str]:
        return reliability(self.imu_rate(), self.min_imu_rate)

    def summary(self) -> ComparisonSummary:
        ok, reason = self.reliability()
        references = {}
        for name, lane in sorted(SOURCES.items()):
            if lane < len(self.src_counts) and self.src_counts[lane, N]:
                sums = self.src_sums[lane].tolist()
                start, end = self.recent.bounds[lane].tolist()
                heads = [self.peaks.rows[3 * lane + i, self.peaks.bounds[3 * lane + i, START], 1] for i in range(3)]
                references[name] = reference_summary(
                    int(self.src_counts[lane, N]), sums[SUM_SQ : SUM_SQ + 3], sums[TOP : TOP + 3], end - start,
                    sums[WINDOW_SUM_SQ : WINDOW_SUM_SQ + 3], [float(h) for h in heads],
                )  # fmt: skip
        return {
            "reliable": ok,
            "reason": reason,
            "imu_rate": self.imu_rate(),
            "lag": self.lag(),
            "dropped": self.dropped,
            "references": references,
        }


def warm() -> None:
    """Compile (or load from the disk cache) the kernel now, off the live loop."""
    c = CompiledComparison(window=0.05, history=0.1, lag_max=0.02)
    for k in range(40):
        t = 0.01 * k
        c.add_estimate(t, (1.0, 0.0, 0.0, 0.0))
        c.add_reference(AttitudeSample(t + 0.001, 0.0, 0.0, 0.0, "onboard"))
    fsum(np.ones(3))
