"""One estimator over a whole recording in one compiled loop: what-if and replay at array speed.

The live path calls an estimator once per sample from Python; over a recording that call, the
per-sample objects and the plausibility check around it cost ten times the filter. Here the
inputs stay in the columns `gcs.logs.input_table` keeps (kind per input, IMU and GPS rows) and
`run_inputs` walks them in numba, calling the same step kernels the live path calls, so the
attitudes equal the per-sample path's to rounding (tests/test_whole_run.py). It returns to Python
only where the per-sample path does Python work: a re-initialisation, a gain change, `ekf`'s
velocity history growing.
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
import numpy.typing as npt

from gcs.core.estimation import GainChange
from gcs.core.estimators import ekf_compiled, registry
from gcs.core.estimators import kernels as k
from gcs.core.estimators.base import AttitudeEstimator
from gcs.core.estimators.compiled import Compiled
from gcs.core.estimators.jit import kernel
from gcs.core.estimators.stepping import step_any
from gcs.core.plausibility import gps_rows_accepted, imu_rows_accepted
from gcs.core.samples import ImuSample

Floats = npt.NDArray[np.float64]


class InputKind(IntEnum):
    """What input i of a recording is, and which optional fields it has (the column tables'
    `kind`): IMU rows are t, gyro xyz, accel xyz, mag xyz (NaN without); GPS rows t, lat, lon,
    alt, ground_speed, course, vel_ned xyz (NaN without), fix_type."""

    IMU = 0
    IMU_MAG = 1
    GPS = 2
    GPS_VEL = 3
    ATTITUDE = 4
    GAIN = 5


#: run_inputs' stops besides a step's re-initialisation codes
END, GAIN_CHANGE, GROW = -1, -2, -3


@dataclass(frozen=True)
class WholeRun:
    """Per IMU row: the attitude quaternion (w, x, y, z, sensor → NED) after it, whether it was
    valid then, and whether the estimator saw it at all (`fed`: not refused as implausible)."""

    q: Floats
    valid: npt.NDArray[np.bool_]
    fed: npt.NDArray[np.bool_]


def imu_accepted(kind: npt.NDArray[np.generic], imu: Floats) -> npt.NDArray[np.bool_]:
    """plausibility.refusal(...) is None for every IMU row, on whole columns."""
    mag = kind[(kind == InputKind.IMU) | (kind == InputKind.IMU_MAG)] == InputKind.IMU_MAG
    accepted: npt.NDArray[np.bool_] = imu_rows_accepted(np.ascontiguousarray(imu, dtype=np.float64), mag)
    return accepted


def gps_accepted(kind: npt.NDArray[np.generic], gps: Floats) -> npt.NDArray[np.bool_]:
    """plausibility.refusal(...) is None for every GPS row, on whole columns."""
    vel = kind[(kind == InputKind.GPS) | (kind == InputKind.GPS_VEL)] == InputKind.GPS_VEL
    return gps_rows_accepted(gps, vel)


@kernel
def _gps(which: int, s: Floats, hist: Floats, g: Floats, row: Floats, has_vel: bool) -> None:
    if which == k.EKF:
        ekf_compiled.gps_input(s, hist, g, row[0], row[9], row[6:9], has_vel, row[4], row[5])
    else:
        k.gps_input(s, hist, g, row[0], row[9], row[6:9], has_vel, row[4], row[5])


@kernel
def run_inputs(
    which: int, s: Floats, hist: Floats, g: Floats, valid_slot: int, hist_n_slot: int,
    kind: npt.NDArray[np.uint8], imu: Floats, imu_ok: npt.NDArray[np.bool_], gps_rows: Floats,
    gps_ok: npt.NDArray[np.bool_], i: int, r_imu: int, r_gps: int, out_q: Floats, out_valid: npt.NDArray[np.bool_],
) -> tuple[int, int, int, int]:  # fmt: skip
    """Feed inputs i.. to estimator `which`'s kernels (compiled.Kernels) until the end, a gain change,
    a step that asks for a re-initialisation (its code; the row is then not written), or a full
    history (GROW; not stepped). Returns (input index, IMU row, GPS row, why it stopped)."""
    n = len(kind)
    while i < n:
        kd = kind[i]
        if kd <= 1:
            if imu_ok[r_imu]:
                if hist_n_slot >= 0 and s[hist_n_slot] >= hist.shape[0] - 1:
                    return i, r_imu, r_gps, GROW
                code = step_any(which, s, hist, g, imu[r_imu], kd == 1)
                if code == k.STEP:
                    out_valid[r_imu] = True
                elif code == k.DUPLICATE:
                    out_valid[r_imu] = s[valid_slot] != 0.0
                else:
                    return i, r_imu, r_gps, code
                for j in range(4):
                    out_q[r_imu, j] = s[k.Q + j]
            r_imu += 1
        elif kd <= 3:
            if gps_ok[r_gps]:
                _gps(which, s, hist, g, gps_rows[r_gps], kd == 3)
            r_gps += 1
        elif kd == 5:
            return i, r_imu, r_gps, GAIN_CHANGE
        i += 1
    return i, r_imu, r_gps, END


def run_whole(
    estimator: AttitudeEstimator,
    kind: npt.NDArray[np.generic],
    imu: Floats,
    gps: Floats,
    gain_change: Callable[[int], GainChange],
    name: str | None = None,
    pinned: Collection[str] = (),
) -> WholeRun:
    """gcs.core.estimation.run_estimator over column inputs (kind per input; IMU and GPS rows in
    input order; gain_change(k): the k-th GAIN input), for a compiled estimator: the same
    refusals, gain rules and results. Reference attitudes are skipped."""
    if not isinstance(estimator, Compiled):
        raise TypeError(f"{type(estimator).__name__} has no compiled kernels")
    kernels = estimator.KERNELS
    imu_ok, gps_ok = imu_accepted(kind, imu), gps_accepted(kind, gps)
    n_imu = len(imu)
    out_q, out_valid = np.zeros((n_imu, 4)), np.zeros(n_imu, dtype=np.bool_)
    imu_c, gps_c = np.ascontiguousarray(imu), np.ascontiguousarray(gps)
    kind_c = np.ascontiguousarray(kind, dtype=np.uint8)
    i = r_imu = r_gps = gains_seen = 0
    while True:
        i, r_imu, r_gps, why = run_inputs(
            kernels.step, estimator.s, estimator.hist, estimator.gain_vector(),
            kernels.valid_slot, kernels.hist_n_slot, kind_c, imu_c, imu_ok, gps_c, gps_ok,
            i, r_imu, r_gps, out_q, out_valid,
        )  # fmt: skip
        if why == END:
            return WholeRun(out_q, out_valid, imu_ok)
        if why == GROW:
            estimator._grow()
            continue
        if why == GAIN_CHANGE:
            change = gain_change(gains_seen)
            gains_seen += 1
            if (
                change.estimator in (None, name)
                and change.name not in pinned
                and change.name in estimator.gains.declarations
            ):
                estimator.set_gain(change.name, change.value)
        else:  # a re-initialisation: the rest of update_imu, in Python as on the per-sample path
            row = imu_c[r_imu]
            mag = row[7:10].copy() if kind_c[i] == InputKind.IMU_MAG else None
            out_valid[r_imu] = estimator._after_step(
                int(why), ImuSample(float(row[0]), row[1:4].copy(), row[4:7].copy(), mag)
            )
            out_q[r_imu] = estimator.s[k.Q : k.Q + 4]
            r_imu += 1
        i += 1


@kernel
def euler_of(q: Floats) -> Floats:
    """rotation.quat_to_euler of every row of q (N×4) → N×3 (roll, pitch, yaw)."""
    out = np.empty((q.shape[0], 3))
    for i in range(q.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = k.quat_to_euler((q[i, 0], q[i, 1], q[i, 2], q[i, 3]))
    return out


@kernel
def _attitude_errors(t: Floats, q: Floats, ref: Floats, lo: npt.NDArray[np.int64], hi: npt.NDArray[np.int64]) -> Floats:
    """comparison.attitude_error of each reference row against outputs lo..hi, as errors_at."""
    out = np.empty((ref.shape[0], 4))
    last = len(t) - 1
    for m in range(ref.shape[0]):
        rt = ref[m, 0]
        i, j = lo[m], hi[m]
        if rt >= t[last]:
            i = j = last
        span = t[j] - t[i]
        u = (rt - t[i]) / span if span > 0 else 0.0
        q0 = (q[i, 0], q[i, 1], q[i, 2], q[i, 3])
        q1 = (q[j, 0], q[j, 1], q[j, 2], q[j, 3])
        out[m, 0] = rt
        out[m, 1], out[m, 2], out[m, 3] = k.attitude_error(q0, q1, u, ref[m, 1], ref[m, 2], ref[m, 3])
    return out


def errors_at(t: Floats, q: Floats, reference: Floats) -> Floats:
    """comparison.errors_at compiled: the same references scored the same way, for whole runs."""
    if len(t) < 1 or len(reference) == 0:
        return np.empty((0, 4))
    inside = (reference[:, 0] >= t[0]) & (reference[:, 0] <= t[-1])
    ref = np.ascontiguousarray(reference[inside], dtype=np.float64)
    hi = np.minimum(np.searchsorted(t, ref[:, 0], side="right"), len(t) - 1)
    lo = np.maximum(hi - 1, 0)
    return _attitude_errors(np.ascontiguousarray(t), np.ascontiguousarray(q), ref, lo, hi)


def warm() -> None:
    """Compile (or load from the disk cache) the whole-run loop and the error kernels now, on a
    few synthetic inputs of every kind, so that a process's first what-if does not wait for it."""
    kind = np.array([InputKind.IMU_MAG, InputKind.IMU, InputKind.GPS_VEL, InputKind.IMU_MAG], dtype=np.uint8)
    imu = np.array([[0.01 * i, 0.01, -0.02, 0.03, 0.1, 0.2, -9.8, 0.2, 0.01, 0.4] for i in range(3)])
    gps = np.array([[0.015, 0.0, 0.0, 0.0, 5.0, 0.1, 5.0, 0.5, 0.0, 3.0]])
    for name in registry.names():
        run = run_whole(registry.create(name), kind, imu, gps, lambda _: GainChange(None, "", 0.0), name)
        errors_at(imu[:, 0], run.q, np.array([[0.015, 0.0, 0.0, 0.0]]))
        euler_of(run.q)
