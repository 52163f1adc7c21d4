"""Compiled (numba) transcriptions of what every estimator shares — the time policy, the
magnetometer test (magnetic.py), the shock detector and the GPS acceleration (base.py) — over
one float64 state array per estimator. The Python classes stay the reference; these equal them
to rounding (tests/test_compiled_estimators.py). The Python side of a compiled estimator, over
the same array, is gcs.core.estimators.compiled.

State layout: this module owns slots [0, BASE); each estimator's kernel module lays out its own
from BASE. Booleans are 0.0/1.0, "None" is a 0.0 flag slot (or NaN for a time).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from numpy.lib.stride_tricks import as_strided

from gcs.core import rotation
from gcs.core.estimators.jit import kernel
from gcs.core.estimators.magnetic import (
    MAG_CURRENT_TAU,
    MAG_GAINS,
    MAG_HEADING_MIN_GYR,
    MAG_NEW_MIN_GYR,
    MAG_OFFSET_HOLD,
    MAG_OFFSET_HOLD_SPIN2,
    MAG_OFFSET_RAMP,
    MAG_OFFSET_SWING,
    MAG_OFFSET_TURN,
    MAG_REF_TAU,
    MAG_TIME_SIGMA,
    MAG_WARMUP,
)
from gcs.core.rotation import Vec3

State = npt.NDArray[np.float64]

# -- time policy (AttitudeEstimator._check_time) ----------------------------------------------
T, T_PREV, REINIT_COUNT, DUPLICATES, VALID, ACCEL_NORM = range(6)
#: _check_time's outcomes: integrate, skip a duplicate, or re-initialise (and why)
STEP, DUPLICATE, FIRST, BACK, GAP = range(5)
# -- MagneticHeading ---------------------------------------------------------------------------
NOW_SET, NOW_N, NOW_D, REF_SET, REF_N, REF_D, CAND_SET, CAND_N, CAND_D, CAND_TIME = range(6, 16)
OFFSET = 16  # 3
OFFC_SET, OFFC = 19, 20  # flag, 3
OFF_N, OFF_TIME, OFF_TURN, TRUSTED, DISTURBED, YAW_ERROR, LEARNED, RELEARNED, AGE, DECL = range(23, 33)
# -- Shock --------------------------------------------------------------------------------------
SHOCK_UNTIL, SHOCK_ACTIVE, SHOCK_SATURATED, SHOCK_COUNT = range(33, 37)
# -- GpsAcceleration (written by the Python object after each fix, or by gps_update; read per
# sample); GPS_VEL is the last fix's velocity, meaningful while GPS_T is not NaN --------------
GPS_T, GPS_A, GPS_SPEED, GPS_COURSE, GPS_TIMEOUT = 37, 38, 41, 42, 43
# -- the attitude quaternion (w, x, y, z), sensor → NED, written by every step -----------------
Q = 44
GPS_VEL = 48
WEIGHT, OFFSET_AGE, OFFSET_AGE_SPIN2 = 51, 52, 53  # MagneticHeading.weight, .offset_age, .offset_age_spin2
OFF_ROWS, OFF_SWUNG = 54, 63  # MagneticHeading.offset_rows (9), .offset_swung
REJ_SET, REJ_N, REJ_D = 64, 65, 66  # MagneticHeading.rejected
HEAD_SET, HEAD_CAND, HEAD_N, HEAD_TIME = 67, 68, 69, 70  # MagneticHeading.head_cand, .head_n, .head_time
BASE = 71


def new_state(size: int) -> State:
    s = np.zeros(size)
    s[T] = s[T_PREV] = math.nan
    reset_mag(s)
    reset_shock(s)
    s[GPS_T] = math.nan
    s[GPS_COURSE] = math.nan
    s[GPS_TIMEOUT] = 1.0
    return s


def reset_mag(s: State) -> None:
    """A new MagneticHeading."""
    s[NOW_SET:AGE] = 0.0
    s[AGE] = 0.0
    s[DECL] = math.nan
    s[WEIGHT] = 1.0
    s[OFFSET_AGE] = s[OFFSET_AGE_SPIN2] = math.inf
    s[OFF_ROWS:OFF_SWUNG] = 0.0
    s[OFF_SWUNG] = 0.0
    s[REJ_SET:BASE] = 0.0


def reset_shock(s: State) -> None:
    """A new Shock."""
    s[SHOCK_UNTIL] = -math.inf
    s[SHOCK_ACTIVE] = s[SHOCK_SATURATED] = s[SHOCK_COUNT] = 0.0


def mag_gain_slots(gain_slots: dict[str, int]) -> tuple[int, ...]:
    """Where an estimator's gain vector holds MAG_GAINS and the declination, in that order: the
    magnetic kernels' seven gain arguments."""
    return (*(gain_slots[g.name] for g in MAG_GAINS), gain_slots["declination"])


#: Kernels.step codes. whole.py calls the step kernels by code rather than taking them as
#: arguments: numba does not reuse its disk cache for a function that takes functions.
DCM, KF, EKF = range(3)


# -- compiled ------------------------------------------------------------------------------------


@kernel
def check_time(s: State, t: float, max_gap: float) -> int:
    """AttitudeEstimator._check_time: STEP (s[T] advanced), DUPLICATE, or a re-initialisation code."""
    prev = s[T]
    s[T_PREV] = prev
    if math.isnan(prev):
        code = FIRST
    elif t == prev:
        s[DUPLICATES] += 1.0
        return DUPLICATE
    elif t < prev:
        code = BACK
    elif t - prev > max_gap:
        code = GAP
    else:
        s[T] = t
        return STEP
    s[T] = t
    s[REINIT_COUNT] += 1.0
    return code


@kernel
def wrap_pi(angle: float) -> float:
    a = float(np.fmod(angle + math.pi, 2 * math.pi))  # math.fmod: numba has the ufunc only
    if a <= 0:
        a += 2 * math.pi
    return a - math.pi


@kernel
def shock_update(
    s: State, t: float, accel_norm: float, spin: float, gyro_limit: float, shock_acc: float, hold: float
) -> bool:
    """Shock.update: whether the accelerometer is to be ignored at t."""
    sat = spin > gyro_limit
    s[SHOCK_SATURATED] = 1.0 if sat else 0.0
    if accel_norm > shock_acc or sat:
        if t >= s[SHOCK_UNTIL]:
            s[SHOCK_COUNT] += 1.0
        s[SHOCK_UNTIL] = t + hold
    active = bool(t <= s[SHOCK_UNTIL])
    s[SHOCK_ACTIVE] = 1.0 if active else 0.0
    return active


@kernel
def gps_update(s: State, t: float, fix_type: float, vel: State, has_vel: bool, speed: float, course: float) -> None:
    """GpsAcceleration.update on the state (the whole-run path; the per-sample path keeps the
    Python object and copies it with load_gps)."""
    gt = s[GPS_T]
    if not math.isnan(gt) and t <= gt:
        if t < gt:  # clock went back: start over
            _gps_reset(s)
        return
    if not has_vel or fix_type < 3:
        _gps_reset(s)
        return
    if not math.isnan(gt) and t - gt <= s[GPS_TIMEOUT]:
        for i in range(3):
            s[GPS_A + i] = (vel[i] - s[GPS_VEL + i]) / (t - gt)
    else:
        s[GPS_A], s[GPS_A + 1], s[GPS_A + 2] = 0.0, 0.0, 0.0
    s[GPS_T] = t
    s[GPS_VEL], s[GPS_VEL + 1], s[GPS_VEL + 2] = vel[0], vel[1], vel[2]
    s[GPS_SPEED], s[GPS_COURSE] = speed, course


@kernel
def gps_input(
    s: State, hist: State, g: State, t: float, fix_type: float, vel: State, has_vel: bool, speed: float, course: float
) -> None:
    """`dcm` and `kf`'s GPS input in the shared signature (ekf_compiled.gps_input's): the acceleration."""
    gps_update(s, t, fix_type, vel, has_vel, speed, course)


@kernel
def _gps_reset(s: State) -> None:
    """GpsAcceleration.reset."""
    s[GPS_T] = math.nan
    s[GPS_A], s[GPS_A + 1], s[GPS_A + 2] = 0.0, 0.0, 0.0
    s[GPS_SPEED], s[GPS_COURSE] = 0.0, math.nan


@kernel
def gps_at(s: State, t: float) -> Vec3:
    """GpsAcceleration.at."""
    gt = s[GPS_T]
    if math.isnan(gt) or abs(t - gt) > s[GPS_TIMEOUT]:
        return 0.0, 0.0, 0.0
    return s[GPS_A], s[GPS_A + 1], s[GPS_A + 2]


@kernel
def gps_course_at(s: State, t: float, speed_min: float) -> float:
    """GpsAcceleration.course_at; NaN for None."""
    gt = s[GPS_T]
    if math.isnan(gt) or abs(t - gt) > s[GPS_TIMEOUT] or not s[GPS_SPEED] >= speed_min:
        return math.nan
    return float(s[GPS_COURSE])


@kernel
def _accept(s: State) -> None:
    s[DISTURBED] = 0.0
    s[CAND_SET] = 0.0
    s[CAND_TIME] = 0.0
    s[OFFC_SET] = 0.0
    s[OFF_N] = 0.0
    s[OFF_TIME] = 0.0
    s[OFF_TURN] = 0.0


@kernel
def _distance(norm: float, dip: float, ref_n: float, ref_d: float, tol_n: float, tol_d: float) -> float:
    """magnetic._distance."""
    dn = (norm - ref_n) / max(tol_n * ref_n, 1e-9)
    dd = (dip - ref_d) / max(tol_d, 1e-9)
    return dn * dn + dd * dd


@kernel
def _new_heading(s: State, ye: float, dt: float, spin: float, tol_h: float, relearn: float) -> bool:
    """MagneticHeading._new_heading."""
    c = s[HEAD_CAND]
    if s[HEAD_SET] == 0.0 or abs(wrap_pi(ye - c)) > tol_h + spin * MAG_TIME_SIGMA:
        s[HEAD_SET], s[HEAD_CAND], s[HEAD_N], s[HEAD_TIME] = 1.0, ye, 1.0, 0.0
        return False
    s[HEAD_N] += 1.0
    c = c + wrap_pi(ye - c) / s[HEAD_N]
    s[HEAD_CAND] = c
    if abs(c) <= 0.5 * tol_h:
        s[HEAD_SET], s[HEAD_N], s[HEAD_TIME] = 0.0, 0.0, 0.0
        return False
    if spin >= MAG_HEADING_MIN_GYR:
        s[HEAD_TIME] += dt
        if s[HEAD_TIME] >= relearn:
            s[HEAD_SET], s[HEAD_N], s[HEAD_TIME] = 0.0, 0.0, 0.0
            return True
    return False


@kernel
def mag_field(
    s: State, m0: float, m1: float, m2: float, X: Vec3, Y: Vec3, Z: Vec3, dt: float, spin: float,
    gm: tuple[float, float, float, float, float, float, float], settling: bool,
) -> tuple[bool, float, float, float]:  # fmt: skip
    """MagneticHeading.field: (usable, m − b). gm = (norm_tol, dip_tol, heading_tol, relearn,
    offset_time, offset_tol, declination)."""
    tol_n, tol_d, tol_h, relearn, off_time, off_tol, decl = gm
    s[OFFSET_AGE] += dt
    s[OFFSET_AGE_SPIN2] += spin * spin * dt
    after_time = (s[OFFSET_AGE] - MAG_OFFSET_HOLD) / MAG_OFFSET_RAMP
    after_spin = (s[OFFSET_AGE_SPIN2] - MAG_OFFSET_HOLD_SPIN2) / MAG_OFFSET_HOLD_SPIN2
    s[WEIGHT] = min(max(after_time, after_spin, 0.0), 1.0)
    bx, by, bz = s[OFFSET], s[OFFSET + 1], s[OFFSET + 2]
    mc0, mc1, mc2 = m0 - bx, m1 - by, m2 - bz
    hn = X[0] * mc0 + X[1] * mc1 + X[2] * mc2
    he = Y[0] * mc0 + Y[1] * mc1 + Y[2] * mc2
    hd = Z[0] * mc0 + Z[1] * mc1 + Z[2] * mc2
    h = math.hypot(hn, he)
    if h < 1e-9:
        return False, 0.0, 0.0, 0.0
    norm, dip = math.hypot(h, hd), math.atan2(hd, h)
    # _low_pass
    if s[NOW_SET] == 0.0 or dt <= 0.0:
        s[NOW_SET], s[NOW_N], s[NOW_D] = 1.0, norm, dip
    else:
        a = dt / (MAG_CURRENT_TAU + dt)
        s[NOW_N] = s[NOW_N] + a * (norm - s[NOW_N])
        s[NOW_D] = s[NOW_D] + a * (dip - s[NOW_D])
    norm, dip = s[NOW_N], s[NOW_D]
    if settling:
        s[AGE] = 0.0
    if s[AGE] < MAG_WARMUP:
        s[AGE] += dt
        if s[REF_SET] == 0.0 or abs(norm - s[REF_N]) > 0.25 * tol_n * s[REF_N] or abs(dip - s[REF_D]) > 0.25 * tol_d:
            s[REF_SET], s[REF_N], s[REF_D], s[AGE] = 1.0, norm, dip, 0.0
        s[TRUSTED] = 0.0
    n0, d0 = s[REF_N], s[REF_D]
    if decl != s[DECL]:
        s[DECL] = decl
        s[TRUSTED] = 0.0
    ye = wrap_pi(decl - math.atan2(he, hn))
    s[YAW_ERROR] = ye
    fits = abs(norm - n0) <= tol_n * n0 and abs(dip - d0) <= tol_d
    if s[TRUSTED] != 0.0 and _new_heading(s, ye, dt, spin, tol_h, relearn):
        s[TRUSTED] = 0.0
        s[REJ_SET], s[REJ_N], s[REJ_D] = 1.0, n0, d0
        s[REF_N], s[REF_D] = norm, dip
        n0, d0 = norm, dip
        fits = True
    if fits and s[REJ_SET] != 0.0:
        fits = _distance(norm, dip, s[REJ_N], s[REJ_D], tol_n, tol_d) > _distance(norm, dip, n0, d0, tol_n, tol_d)
    agrees = abs(ye) <= tol_h + spin * MAG_TIME_SIGMA or s[TRUSTED] == 0.0
    if fits and agrees:
        a = dt / (MAG_REF_TAU + dt)
        s[REF_N], s[REF_D] = n0 + a * (norm - n0), d0 + a * (dip - d0)
        _accept(s)
        if abs(ye) <= 0.5 * tol_h:
            s[TRUSTED] = 1.0
        return True, mc0, mc1, mc2
    s[DISTURBED] = 1.0
    # _hard_iron: the sensor-frame offset o = m − Rᵀ m_E, timed
    e0 = n0 * math.cos(d0) * math.cos(decl)
    e1 = n0 * math.cos(d0) * math.sin(decl)
    e2 = n0 * math.sin(d0)
    o0 = m0 - (X[0] * e0 + Y[0] * e1 + Z[0] * e2)
    o1 = m1 - (X[1] * e0 + Y[1] * e1 + Z[1] * e2)
    o2 = m2 - (X[2] * e0 + Y[2] * e1 + Z[2] * e2)
    learned = False
    c0, c1, c2 = s[OFFC], s[OFFC + 1], s[OFFC + 2]
    if s[OFFC_SET] == 0.0 or math.sqrt((o0 - c0) ** 2 + (o1 - c1) ** 2 + (o2 - c2) ** 2) > off_tol * n0:
        s[OFFC_SET], s[OFFC], s[OFFC + 1], s[OFFC + 2] = 1.0, o0, o1, o2
        s[OFF_N], s[OFF_TIME], s[OFF_TURN] = 1.0, 0.0, 0.0
        for i in range(3):
            s[OFF_ROWS + i], s[OFF_ROWS + 3 + i], s[OFF_ROWS + 6 + i] = X[i], Y[i], Z[i]
        s[OFF_SWUNG] = 0.0
    else:
        r = OFF_ROWS
        sx = (X[0] - s[r]) * c0 + (X[1] - s[r + 1]) * c1 + (X[2] - s[r + 2]) * c2
        sy = (Y[0] - s[r + 3]) * c0 + (Y[1] - s[r + 4]) * c1 + (Y[2] - s[r + 5]) * c2
        sz = (Z[0] - s[r + 6]) * c0 + (Z[1] - s[r + 7]) * c1 + (Z[2] - s[r + 8]) * c2
        if sx * sx + sy * sy + sz * sz >= MAG_OFFSET_SWING**2 * (c0 * c0 + c1 * c1 + c2 * c2):
            s[OFF_SWUNG] = 1.0
        s[OFF_N] += 1.0
        k = 1.0 / s[OFF_N]
        s[OFFC], s[OFFC + 1], s[OFFC + 2] = c0 + k * (o0 - c0), c1 + k * (o1 - c1), c2 + k * (o2 - c2)
        s[OFF_TIME] += dt
        s[OFF_TURN] += spin * dt
        turned = s[OFF_TURN] >= MAG_OFFSET_TURN and s[OFF_SWUNG] != 0.0
        if s[OFF_TIME] >= off_time and turned:
            s[OFFSET], s[OFFSET + 1], s[OFFSET + 2] = s[OFFC], s[OFFC + 1], s[OFFC + 2]
            learned = True
    if learned:
        s[NOW_SET] = 0.0
        s[OFFSET_AGE], s[OFFSET_AGE_SPIN2], s[WEIGHT] = 0.0, 0.0, 0.0
        s[LEARNED] += 1.0
        _accept(s)
        return True, m0 - s[OFFSET], m1 - s[OFFSET + 1], m2 - s[OFFSET + 2]
    # _new_field: a steady new (norm, dip) while turning
    relearn_now = False
    if s[CAND_SET] == 0.0 or abs(norm - s[CAND_N]) > tol_n * s[CAND_N] or abs(dip - s[CAND_D]) > tol_d:
        s[CAND_SET], s[CAND_N], s[CAND_D], s[CAND_TIME] = 1.0, norm, dip, 0.0
    elif spin >= MAG_NEW_MIN_GYR:
        s[CAND_TIME] += dt
        relearn_now = s[CAND_TIME] >= relearn
    if relearn_now:
        s[REF_SET], s[REF_N], s[REF_D] = 1.0, norm, dip
        s[RELEARNED] += 1.0
        s[TRUSTED] = 0.0
        _accept(s)
        return True, mc0, mc1, mc2
    return False, 0.0, 0.0, 0.0


@kernel
def rows_to_quat(s: State, rows: int) -> None:
    """rotation.matrix_to_quat of the 3×3 rows at s[rows:rows+9], into s[Q:Q+4] (Shepperd)."""
    r00, r01, r02 = s[rows], s[rows + 1], s[rows + 2]
    r10, r11, r12 = s[rows + 3], s[rows + 4], s[rows + 5]
    r20, r21, r22 = s[rows + 6], s[rows + 7], s[rows + 8]
    trace = r00 + r11 + r22
    if trace > 0:
        sq = 2.0 * math.sqrt(1.0 + trace)
        w, x, y, z = 0.25 * sq, (r21 - r12) / sq, (r02 - r20) / sq, (r10 - r01) / sq
    elif r00 > r11 and r00 > r22:
        sq = 2.0 * math.sqrt(1.0 + r00 - r11 - r22)
        w, x, y, z = (r21 - r12) / sq, 0.25 * sq, (r01 + r10) / sq, (r02 + r20) / sq
    elif r11 > r22:
        sq = 2.0 * math.sqrt(1.0 + r11 - r00 - r22)
        w, x, y, z = (r02 - r20) / sq, (r01 + r10) / sq, 0.25 * sq, (r12 + r21) / sq
    else:
        sq = 2.0 * math.sqrt(1.0 + r22 - r00 - r11)
        w, x, y, z = (r10 - r01) / sq, (r02 + r20) / sq, (r12 + r21) / sq, 0.25 * sq
    n = math.sqrt(w * w + x * x + y * y + z * z)
    sign = -1.0 if w / n < 0 else 1.0
    s[Q], s[Q + 1], s[Q + 2], s[Q + 3] = sign * w / n, sign * x / n, sign * y / n, sign * z / n


@kernel
def matrix(s: State, at: int, rows: int, cols: int) -> State:
    """The rows×cols matrix kept row by row at s[at:], as a view. Not `reshape`: its no-copy check
    is a call into numba's helper library (~15 ns), several per step; the state's layout
    guarantees the room."""
    return as_strided(s[at:], (rows, cols), (cols * s.itemsize, s.itemsize))


# rotation.py's plain-float formulas, compiled from the same source (one copy of each formula)
quat_exp = kernel(rotation.quat_exp)
quat_mul = kernel(rotation.quat_mul)
quat_unit = kernel(rotation.quat_unit)
quat_rows = kernel(rotation.quat_rows)
euler_quat = kernel(rotation.euler_quat)
quat_to_euler = kernel(rotation.quat_to_euler)
quat_slerp = kernel(rotation.quat_slerp)


@kernel
def attitude_error(
    q0: tuple[float, float, float, float], q1: tuple[float, float, float, float], u: float, roll: float, pitch: float,
    yaw: float,
) -> tuple[float, float, float]:  # fmt: skip
    """comparison.attitude_error compiled: the live comparison scores every reference with it and
    the whole-run errors every row (equal to the Python function bit for bit,
    tests/test_comparison_incremental.py)."""
    est_roll, est_pitch, est_yaw = quat_to_euler(quat_slerp(q0, q1, u))
    return (
        math.degrees(wrap_pi(est_roll - roll)),
        math.degrees(wrap_pi(est_pitch - pitch)),
        math.degrees(wrap_pi(est_yaw - yaw)),
    )


@kernel
def attitude_of(s: State) -> tuple[tuple[float, float, float, float], tuple[float, float, float]]:
    """The state's quaternion and its Z-Y-X angles (rotation.quat_to_euler), as plain floats."""
    q = (s[Q], s[Q + 1], s[Q + 2], s[Q + 3])
    return q, quat_to_euler(q)
