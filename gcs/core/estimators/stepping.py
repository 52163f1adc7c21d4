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
from typing import TypeAlias

import numpy as np
import numpy.typing as npt

from gcs.core.estimators import dcm_compiled, ekf_compiled, kf_compiled, registry
from gcs.core.estimators import kernels as k
from gcs.core.estimators.base import AttitudeEstimator
from gcs.core.estimators.compiled import Compiled
from gcs.core.estimators.jit import kernel
from gcs.core.plausibility import imu_row_accepted
from gcs.core.samples import ImuSample

Floats = npt.NDArray[np.float64]
Bools = npt.NDArray[np.bool_]

#: step_rows' stops besides a step's re-initialisation codes
END, GROW, NON_FINITE = -1, -3, -4
#: ImuBatch.rows' columns: t, gyro xyz, accel xyz, mag xyz (zero without one, as update_imu
#: passes the kernels), 1.0 where the sample has a field
T, GYRO, ACCEL, MAG, HAS_MAG, ROW = 0, 1, 4, 7, 10, 11
#: BatchAttitudes.rows' columns: quaternion w x y z, roll pitch yaw, valid, stepped (0.0 / 1.0)
Q, EULER, VALID, STEPPED, OUT = 0, 4, 7, 8, 9
_NO_FIELD = (0.0, 0.0, 0.0, 0.0)

#: One IMU sample as its ImuBatch row (the ROW columns above, Python floats): what the live path
#: builds from an IMU message instead of an ImuSample (gcs.mavlink.sampling.MessageSampler.imu_row),
#: when all the pipeline needs of it is the row. A plain tuple: one is built per IMU message.
ImuRow: TypeAlias = tuple[float, ...]


def imu_sample_of(row: ImuRow) -> ImuSample:
    """The ImuSample a row stands for (where a part needs the sample: `feed`, a refusal's reason)."""
    return ImuSample(
        row[T],
        np.array(row[GYRO:ACCEL]),
        np.array(row[ACCEL:MAG]),
        np.array(row[MAG:HAS_MAG]) if row[HAS_MAG] else None,
    )


@dataclass(frozen=True, slots=True)
class ImuBatch:
    """Consecutive IMU samples as one n×ROW table (the columns above), so that a batch costs a
    few NumPy calls and one compiled call per estimator, whatever its size."""

    rows: Floats

    @classmethod
    def of(cls, samples: Sequence[ImuSample | ImuRow]) -> ImuBatch:
        """The table of samples, each an ImuSample or already its row."""
        flat: list[float] = []
        for sample in samples:
            if isinstance(sample, tuple):
                flat += sample
                continue
            flat.append(sample.t)
            flat += sample.gyro.tolist()
            flat += sample.accel.tolist()
            if sample.mag is None:
                flat += _NO_FIELD
            else:
                flat += sample.mag.tolist()
                flat.append(1.0)
        return cls(np.array(flat, dtype=np.float64).reshape(-1, ROW))

    def take(self, rows: Bools) -> ImuBatch:
        """The rows where `rows` is True."""
        return ImuBatch(self.rows[rows])

    def __len__(self) -> int:
        return len(self.rows)

    def sample(self, i: int) -> ImuSample:
        """Row i as the sample it was (for the Python part of a re-initialisation)."""
        row = self.rows[i]
        mag = row[MAG:HAS_MAG].copy() if row[HAS_MAG] else None
        return ImuSample(float(row[T]), row[GYRO:ACCEL].copy(), row[ACCEL:MAG].copy(), mag)


@dataclass(frozen=True, slots=True)
class BatchAttitudes:
    """One estimator's outputs over an ImuBatch, one n×OUT table (the columns above): per row the
    quaternion (w, x, y, z) and its Z-Y-X angles (rad) after it, whether they were valid then, and
    whether the row gave an estimate at all (`stepped`: not where the estimator faulted)."""

    rows: Floats

    @classmethod
    def empty(cls, n: int) -> BatchAttitudes:
        return cls(np.zeros((n, OUT)))


@kernel
def accepted_rows(rows: Floats) -> Bools:
    """plausibility.refusal(...) is None, for every row of an ImuBatch."""
    out = np.empty(rows.shape[0], dtype=np.bool_)
    for i in range(rows.shape[0]):
        out[i] = imu_row_accepted(rows[i], rows[i, HAS_MAG] != 0.0)
    return out


@kernel
def step_any(which: int, s: Floats, hist: Floats, g: Floats, row: Floats, has_mag: bool) -> int:
    """Estimator `which`'s step kernel (kernels.DCM ...) on one row of an IMU table."""
    if which == k.DCM:
        return dcm_compiled.step(s, hist, g, row[0], row[1:4], row[4:7], row[7:10], has_mag)
    if which == k.KF:
        return kf_compiled.step(s, hist, g, row[0], row[1:4], row[4:7], row[7:10], has_mag)
    return ekf_compiled.step(s, hist, g, row[0], row[1:4], row[4:7], row[7:10], has_mag)


@kernel
def write_attitude(s: Floats, out: Floats) -> bool:
    """The state's quaternion and angles (kernels.attitude_of) into an output row; whether finite."""
    q, euler = k.attitude_of(s)
    out[Q], out[Q + 1], out[Q + 2], out[Q + 3] = q
    out[EULER], out[EULER + 1], out[EULER + 2] = euler
    return math.isfinite(q[0] + q[1] + q[2] + q[3])


@kernel
def step_rows(
    which: int, s: Floats, hist: Floats, g: Floats, valid_slot: int, hist_n_slot: int, rows: Floats, i: int,
    out: Floats,
) -> tuple[int, int]:  # fmt: skip
    """Step estimator `which` over rows i.. until the end, a step that asks for a
    re-initialisation (its code; the row is then not written), a full history (GROW; not
    stepped) or a non-finite attitude (NON_FINITE; the row is not marked stepped). Returns (row,
    why it stopped). An error inside a step leaves its row the first one not stepped."""
    n = rows.shape[0]
    while i < n:
        if hist_n_slot >= 0 and s[hist_n_slot] >= hist.shape[0] - 1:
            return i, GROW
        code = step_any(which, s, hist, g, rows[i], rows[i, HAS_MAG] != 0.0)
        if code == k.STEP:
            out[i, VALID] = 1.0
        elif code == k.DUPLICATE:
            out[i, VALID] = 1.0 if s[valid_slot] != 0.0 else 0.0
        else:
            return i, code
        if not write_attitude(s, out[i]):
            return i, NON_FINITE
        out[i, STEPPED] = 1.0
        i += 1
    return i, END


@dataclass(frozen=True, slots=True)
class Fault:
    """Why an estimator must restart at row `row` of a batch (the row gives no estimate)."""

    row: int
    reason: str


def step_batch(est: Compiled, batch: ImuBatch, start: int, out: BatchAttitudes) -> Fault | None:
    """`est.update_imu` then `est.attitude()` for every row from `start` on, into `out`; None at the
    end, or the fault at which the pipeline restarts the estimator (an error, a non-finite state),
    as the per-sample path restarts it: the caller goes on from the next row with a new one."""
    kernels = est.KERNELS
    rows, table = batch.rows, out.rows
    i = start
    while i < len(rows):
        try:
            i, why = step_rows(
                kernels.step, est.s, est.hist, est.gain_vector(), kernels.valid_slot, kernels.hist_n_slot, rows, i,
                table,
            )  # fmt: skip
        except Exception as exc:  # as update_imu's error: the pipeline restarts it
            while table[i, STEPPED]:
                i += 1
            return Fault(i, f"{type(exc).__name__}: {exc}")
        if why == END:
            return None
        if why == GROW:
            est._grow()
            continue
        if why == NON_FINITE:
            return Fault(i, f"non-finite state at t={rows[i, T]:.3f} s")
        try:  # a re-initialisation: the rest of update_imu, in Python as on the per-sample path
            table[i, VALID] = est._after_step(int(why), batch.sample(i))
        except Exception as exc:
            return Fault(i, f"{type(exc).__name__}: {exc}")
        if not write_attitude(est.s, table[i]):
            return Fault(i, f"non-finite state at t={rows[i, T]:.3f} s")
        table[i, STEPPED] = 1.0
        i += 1
    return None


def step_samples(est: AttitudeEstimator, batch: ImuBatch, start: int, out: BatchAttitudes) -> Fault | None:
    """`step_batch` for an estimator without compiled kernels (a reference one): per sample."""
    for i in range(start, len(batch)):
        try:
            valid = est.update_imu(batch.sample(i))
        except Exception as exc:  # as step_batch
            return Fault(i, f"{type(exc).__name__}: {exc}")
        (w, x, y, z), (roll, pitch, yaw) = est.attitude()
        if not math.isfinite(w + x + y + z):
            return Fault(i, f"non-finite state at t={batch.rows[i, T]:.3f} s")
        out.rows[i] = w, x, y, z, roll, pitch, yaw, float(valid), 1.0
    return None


def warm() -> None:
    """Compile (or load from the disk cache) the batch stepping now, off the live loop."""
    gyro, accel, mag = np.array([0.01, -0.02, 0.03]), np.array([0.1, 0.2, -9.8]), np.array([0.2, 0.01, 0.4])
    batch = ImuBatch.of([ImuSample(0.01 * i, gyro, accel, mag if i != 1 else None) for i in range(4)])
    accepted_rows(batch.rows)
    for name in registry.names():
        est = registry.create(name)
        if isinstance(est, Compiled):
            step_batch(est, batch, 0, BatchAttitudes.empty(len(batch)))
