"""A compiled estimator stepped over a batch of IMU samples in one compiled call, resumably.

The live pipeline used to call each estimator once per sample from Python (the `update_imu`
wrapper, then `attitude()`): in the serving process, between two turns of the event loop, each
of those calls cost 8-10 µs against 2-3 µs in a microbenchmark (issue 17). Here a tick's IMU
samples become columns (`ImuBatch`) and `step_batch` walks them with the same step kernels
`update_imu` calls, in the estimator's own state: the live estimator object stays the one that
holds the state, so a gain change, a GPS fix or a restart between two batches acts exactly where
it did per sample. It returns to Python only where the per-sample path does Python work (a
re-initialisation, `ekf`'s velocity history growing) and where the pipeline must restart the
estimator (a non-finite attitude, an error), so the outputs equal the per-sample path's bit for
bit (tests/test_batch_stepping.py).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from gcs.core.estimators import dcm_compiled, ekf_compiled, kf_compiled, registry
from gcs.core.estimators import kernels as k
from gcs.core.estimators.base import AttitudeEstimator
from gcs.core.estimators.jit import kernel
from gcs.core.samples import ImuSample

Floats = npt.NDArray[np.float64]
Bools = npt.NDArray[np.bool_]

#: step_rows' stops besides a step's re-initialisation codes
END, GROW, NON_FINITE = -1, -3, -4
#: a row's field where its sample has none (update_imu passes the kernels zeros)
NO_FIELD = np.zeros(3)


@dataclass(frozen=True, slots=True)
class ImuBatch:
    """Consecutive IMU samples as columns: `rows` n×10 (t, gyro xyz, accel xyz, mag xyz; a
    zero field where a sample has none, as `update_imu` passes one) and `has_mag` per row."""

    rows: Floats
    has_mag: Bools

    @classmethod
    def of(cls, samples: Sequence[ImuSample]) -> ImuBatch:
        rows = np.empty((len(samples), 10))
        if not samples:  # references only
            return cls(rows, np.zeros(0, dtype=np.bool_))
        rows[:, 0] = [sample.t for sample in samples]
        rows[:, 1:4] = [sample.gyro for sample in samples]
        rows[:, 4:7] = [sample.accel for sample in samples]
        mags = [sample.mag for sample in samples]
        rows[:, 7:10] = [NO_FIELD if mag is None else mag for mag in mags]
        return cls(rows, np.array([mag is not None for mag in mags], dtype=np.bool_))

    def take(self, rows: Bools) -> ImuBatch:
        """The rows where `rows` is True."""
        return ImuBatch(self.rows[rows], self.has_mag[rows])

    def __len__(self) -> int:
        return len(self.rows)

    def sample(self, i: int) -> ImuSample:
        """Row i as the sample it was (for the Python part of a re-initialisation)."""
        row = self.rows[i]
        mag = row[7:10].copy() if self.has_mag[i] else None
        return ImuSample(float(row[0]), row[1:4].copy(), row[4:7].copy(), mag)


@dataclass(frozen=True, slots=True)
class BatchAttitudes:
    """One estimator's outputs over an ImuBatch, per row: the quaternion (w, x, y, z) and its
    Z-Y-X angles (rad) after the row, whether they were valid then, and whether the row gave an
    estimate at all (`stepped`: False where the estimator faulted and restarted)."""

    q: Floats
    euler: Floats
    valid: Bools
    stepped: Bools

    @classmethod
    def empty(cls, n: int) -> BatchAttitudes:
        return cls(np.zeros((n, 4)), np.zeros((n, 3)), np.zeros(n, np.bool_), np.zeros(n, np.bool_))


@kernel
def step_any(which: int, s: Floats, hist: Floats, g: Floats, row: Floats, has_mag: bool) -> int:
    """Estimator `which`'s step kernel (kernels.DCM ...) on one row of an IMU table."""
    if which == k.DCM:
        return dcm_compiled.step(s, hist, g, row[0], row[1:4], row[4:7], row[7:10], has_mag)
    if which == k.KF:
        return kf_compiled.step(s, hist, g, row[0], row[1:4], row[4:7], row[7:10], has_mag)
    return ekf_compiled.step(s, hist, g, row[0], row[1:4], row[4:7], row[7:10], has_mag)


@kernel
def write_attitude(s: Floats, i: int, out_q: Floats, out_euler: Floats) -> bool:
    """The state's quaternion and angles (kernels.attitude_of) into row i; whether finite."""
    q, euler = k.attitude_of(s)
    out_q[i, 0], out_q[i, 1], out_q[i, 2], out_q[i, 3] = q
    out_euler[i, 0], out_euler[i, 1], out_euler[i, 2] = euler
    return math.isfinite(q[0] + q[1] + q[2] + q[3])


@kernel
def step_rows(
    which: int, s: Floats, hist: Floats, g: Floats, valid_slot: int, hist_n_slot: int, rows: Floats,
    has_mag: Bools, i: int, at: npt.NDArray[np.int64], out_q: Floats, out_euler: Floats, out_valid: Bools,
    out_stepped: Bools,
) -> tuple[int, int]:  # fmt: skip
    """Step estimator `which` over rows i.. until the end, a step that asks for a
    re-initialisation (its code; the row is then not written), a full history (GROW; not
    stepped) or a non-finite attitude (NON_FINITE; the row is not marked stepped). `at[0]` is the
    row being stepped, for an error raised inside a kernel. Returns (row, why it stopped)."""
    n = rows.shape[0]
    while i < n:
        if hist_n_slot >= 0 and s[hist_n_slot] >= hist.shape[0] - 1:
            return i, GROW
        at[0] = i
        code = step_any(which, s, hist, g, rows[i], has_mag[i])
        if code == k.STEP:
            out_valid[i] = True
        elif code == k.DUPLICATE:
            out_valid[i] = s[valid_slot] != 0.0
        else:
            return i, code
        if not write_attitude(s, i, out_q, out_euler):
            return i, NON_FINITE
        out_stepped[i] = True
        i += 1
    return i, END


@dataclass(frozen=True, slots=True)
class Fault:
    """Why an estimator must restart at row `row` of a batch (the row gives no estimate)."""

    row: int
    reason: str


def step_batch(est: k.Compiled, batch: ImuBatch, start: int, out: BatchAttitudes) -> Fault | None:
    """`est.update_imu` then `est.attitude()` for every row from `start` on, into `out`; None at the
    end, or the fault at which the pipeline restarts the estimator (an error, a non-finite state),
    as the per-sample path restarts it: the caller goes on from the next row with a new one."""
    kernels = est.KERNELS
    rows, has_mag = batch.rows, batch.has_mag
    at = np.zeros(1, dtype=np.int64)
    i = start
    while i < len(rows):
        try:
            i, why = step_rows(
                kernels.step, est.s, est.hist, est.gain_vector(), kernels.valid_slot, kernels.hist_n_slot,
                rows, has_mag, i, at, out.q, out.euler, out.valid, out.stepped,
            )  # fmt: skip
        except Exception as exc:  # as update_imu's error: the pipeline restarts it
            return Fault(int(at[0]), f"{type(exc).__name__}: {exc}")
        if why == END:
            return None
        if why == GROW:
            est._grow()
            continue
        if why == NON_FINITE:
            return Fault(i, f"non-finite state at t={rows[i, 0]:.3f} s")
        try:  # a re-initialisation: the rest of update_imu, in Python as on the per-sample path
            out.valid[i] = est._after_step(int(why), batch.sample(i))
        except Exception as exc:
            return Fault(i, f"{type(exc).__name__}: {exc}")
        if not write_attitude(est.s, i, out.q, out.euler):
            return Fault(i, f"non-finite state at t={rows[i, 0]:.3f} s")
        out.stepped[i] = True
        i += 1
    return None


def step_samples(est: AttitudeEstimator, batch: ImuBatch, start: int, out: BatchAttitudes) -> Fault | None:
    """`step_batch` for an estimator without compiled kernels (a reference one): per sample."""
    for i in range(start, len(batch)):
        try:
            out.valid[i] = est.update_imu(batch.sample(i))
        except Exception as exc:  # as step_batch
            return Fault(i, f"{type(exc).__name__}: {exc}")
        (w, x, y, z), euler = est.attitude()
        if not math.isfinite(w + x + y + z):
            return Fault(i, f"non-finite state at t={batch.rows[i, 0]:.3f} s")
        out.q[i] = w, x, y, z
        out.euler[i] = euler
        out.stepped[i] = True
    return None


def warm() -> None:
    """Compile (or load from the disk cache) the batch stepping now, off the live loop."""
    gyro, accel, mag = np.array([0.01, -0.02, 0.03]), np.array([0.1, 0.2, -9.8]), np.array([0.2, 0.01, 0.4])
    batch = ImuBatch.of([ImuSample(0.01 * i, gyro, accel, mag if i != 1 else None) for i in range(4)])
    for name in registry.names():
        est = registry.create(name)
        if isinstance(est, k.Compiled):
            step_batch(est, batch, 0, BatchAttitudes.empty(len(batch)))
