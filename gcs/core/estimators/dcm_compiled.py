"""`dcm` at compiled speed: DcmEstimator.update_imu transcribed into one numba kernel over a
float64 state (kernels.py lays out the shared slots). DcmEstimator stays the readable reference;
this equals it to rounding (tests/test_compiled_estimators.py)."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from gcs.core.estimators import kernels as k
from gcs.core.estimators.base import HealthValue, initial_attitude
from gcs.core.estimators.compiled import Kernels, MagView, StartedInPython
from gcs.core.estimators.dcm import OMEGA_I_MAX, SPIN_RATE_LIMIT, DcmEstimator
from gcs.core.estimators.jit import kernel
from gcs.core.estimators.kernels import State
from gcs.core.estimators.rest import REST_SIZE, reset_rest, rest_bias
from gcs.core.rotation import matrix_to_quat, vec3
from gcs.core.samples import G0, ImuSample

_G = {g.name: i for i, g in enumerate(DcmEstimator.GAINS)}
KP_RP, KI_RP, KP_YAW, KI_YAW = _G["kp_rp"], _G["ki_rp"], _G["kp_yaw"], _G["ki_yaw"]
SPIN_GAIN, SPIN_GAIN_YAW, ACCEL_TAU, ACCEL_WEIGHT = (
    _G["spin_gain"],
    _G["spin_gain_yaw"],
    _G["accel_tau"],
    _G["accel_weight"],
)
YAW_SPIN_HALF, ACCEL_DEV_GATE, YAW_ACC_CAP = _G["yaw_spin_half"], _G["accel_dev_gate"], _G["yaw_acc_cap"]
REST_GYRO, REST_ACC, REST_TIME, REST_TAU = _G["rest_gyro"], _G["rest_acc"], _G["rest_time"], _G["rest_bias_tau"]
GPS_GAIN, GPS_SPEED_MIN, DECLINATION, MAX_GAP = _G["gps_gain"], _G["gps_speed_min"], _G["declination"], _G["max_gap"]
SHOCK_ACC, GYRO_LIMIT, SHOCK_HOLD, PICK_DT = _G["shock_acc"], _G["gyro_limit"], _G["shock_hold"], _G["pick_dt"]
M0, M1, M2, M3, M4, M5, M6 = k.mag_gain_slots(_G)

B = k.BASE
ROWS = B  # 9
OMEGA_I, OMEGA_P, OMEGA_Y, GYRO_PREV, CORR_E = B + 9, B + 12, B + 15, B + 18, B + 21
FAVG_SET, FAVG, RAVG = B + 24, B + 25, B + 28
ACCEL_W, RENORM_SIZE, RENORM_MAX, ERROR_RP, ERROR_YAW, YAW_SOURCE, MAG_REJECTED = range(B + 31, B + 38)
ACCEL_DEV = B + 38
REST = B + 39  # RestBias
SIZE = REST + REST_SIZE
#: yaw_source labels by code
YAW_SOURCES = ("none", "mag", "mag_rejected", "gps_course")


@kernel
def _rotate_renormalize(s: State, wx: float, wy: float, wz: float) -> float:
    """dcm.rotate_rows then dcm.renormalize, in place on s[ROWS]; returns the renormalisation size."""
    a2 = wx * wx + wy * wy + wz * wz
    if a2 < 1e-12:
        sn, c = 1.0 - a2 / 6.0, 0.5 - a2 / 24.0
    else:
        a = math.sqrt(a2)
        sn, c = math.sin(a) / a, (1.0 - math.cos(a)) / a2
    m00, m11, m22 = 1.0 + c * (wx * wx - a2), 1.0 + c * (wy * wy - a2), 1.0 + c * (wz * wz - a2)
    m01, m10 = c * wx * wy - sn * wz, c * wx * wy + sn * wz
    m02, m20 = c * wx * wz + sn * wy, c * wx * wz - sn * wy
    m12, m21 = c * wy * wz - sn * wx, c * wy * wz + sn * wx
    r0, r1, r2 = s[ROWS], s[ROWS + 1], s[ROWS + 2]
    x0, x1, x2 = r0 * m00 + r1 * m10 + r2 * m20, r0 * m01 + r1 * m11 + r2 * m21, r0 * m02 + r1 * m12 + r2 * m22
    r0, r1, r2 = s[ROWS + 3], s[ROWS + 4], s[ROWS + 5]
    y0, y1, y2 = r0 * m00 + r1 * m10 + r2 * m20, r0 * m01 + r1 * m11 + r2 * m21, r0 * m02 + r1 * m12 + r2 * m22
    err = 0.5 * (x0 * y0 + x1 * y1 + x2 * y2)
    x0, x1, x2, y0, y1, y2 = x0 - err * y0, x1 - err * y1, x2 - err * y2, y0 - err * x0, y1 - err * x1, y2 - err * x2
    z0, z1, z2 = x1 * y2 - x2 * y1, x2 * y0 - x0 * y2, x0 * y1 - x1 * y0
    nx = x0 * x0 + x1 * x1 + x2 * x2
    ny = y0 * y0 + y1 * y1 + y2 * y2
    nz = z0 * z0 + z1 * z1 + z2 * z2
    sx, sy, sz = 0.5 * (3.0 - nx), 0.5 * (3.0 - ny), 0.5 * (3.0 - nz)
    s[ROWS], s[ROWS + 1], s[ROWS + 2] = x0 * sx, x1 * sx, x2 * sx
    s[ROWS + 3], s[ROWS + 4], s[ROWS + 5] = y0 * sy, y1 * sy, y2 * sy
    s[ROWS + 6], s[ROWS + 7], s[ROWS + 8] = z0 * sz, z1 * sz, z2 * sz
    return float(max(abs(1.0 - nx), abs(1.0 - ny), abs(1.0 - nz)))


@kernel
def step(s: State, hist: State, g: State, t: float, gyro: State, accel: State, mag: State, has_mag: bool) -> int:
    """DcmEstimator.update_imu (hist: unused, the shared signature). Returns the time policy's code
    (kernels.STEP ...); on a re-initialisation code the caller initialises from the sample."""
    gx, gy, gz = gyro[0], gyro[1], gyro[2]
    fx, fy, fz = accel[0], accel[1], accel[2]
    accel_norm = math.sqrt(fx * fx + fy * fy + fz * fz)
    s[k.ACCEL_NORM] = accel_norm
    code = k.check_time(s, t, g[MAX_GAP])
    if code != k.STEP:
        return code
    dt = t - s[k.T_PREV]
    # 1. gyro update with the previous sample's corrections
    if dt > g[PICK_DT]:
        px, py, pz = s[GYRO_PREV], s[GYRO_PREV + 1], s[GYRO_PREV + 2]
    else:
        px, py, pz = gx, gy, gz
    s[GYRO_PREV], s[GYRO_PREV + 1], s[GYRO_PREV + 2] = gx, gy, gz
    wx = 0.5 * (px + gx) + s[OMEGA_I] + s[OMEGA_P] + s[OMEGA_Y]
    wy = 0.5 * (py + gy) + s[OMEGA_I + 1] + s[OMEGA_P + 1] + s[OMEGA_Y + 1]
    wz = 0.5 * (pz + gz) + s[OMEGA_I + 2] + s[OMEGA_P + 2] + s[OMEGA_Y + 2]
    if s[FAVG_SET] != 0.0:
        c0, c1, c2 = s[CORR_E], s[CORR_E + 1], s[CORR_E + 2]
        F0, F1, F2 = s[FAVG], s[FAVG + 1], s[FAVG + 2]
        s[FAVG] = F0 + (c1 * F2 - c2 * F1) * dt
        s[FAVG + 1] = F1 + (c2 * F0 - c0 * F2) * dt
        s[FAVG + 2] = F2 + (c0 * F1 - c1 * F0) * dt
    # 2. renormalisation
    size = _rotate_renormalize(s, wx * dt, wy * dt, wz * dt)
    s[RENORM_SIZE] = size
    s[RENORM_MAX] = max(s[RENORM_MAX], size)
    X = (s[ROWS], s[ROWS + 1], s[ROWS + 2])
    Y = (s[ROWS + 3], s[ROWS + 4], s[ROWS + 5])
    Z = (s[ROWS + 6], s[ROWS + 7], s[ROWS + 8])
    spin = math.sqrt(wx * wx + wy * wy + wz * wz)
    if k.shock_update(
        s, t, accel_norm, math.sqrt(gx * gx + gy * gy + gz * gz), g[GYRO_LIMIT], g[SHOCK_ACC], g[SHOCK_HOLD]
    ):
        if s[k.SHOCK_SATURATED] != 0.0:
            s[k.TRUSTED] = 0.0
    shock_active = s[k.SHOCK_ACTIVE] != 0.0
    # 3. roll-pitch error
    ex = ey = 0.0
    if accel_norm > 1e-6 and not shock_active:
        f0 = X[0] * fx + X[1] * fy + X[2] * fz
        f1 = Y[0] * fx + Y[1] * fy + Y[2] * fz
        f2 = Z[0] * fx + Z[1] * fy + Z[2] * fz
        an, ae, ad = k.gps_at(s, t)
        kg = g[GPS_GAIN]
        r0, r1, r2 = kg * an, kg * ae, kg * ad - G0
        if s[FAVG_SET] != 0.0:
            a = dt / (g[ACCEL_TAU] + dt)
            F0, F1, F2 = s[FAVG], s[FAVG + 1], s[FAVG + 2]
            Q0, Q1, Q2 = s[RAVG], s[RAVG + 1], s[RAVG + 2]
            f0, f1, f2 = F0 + a * (f0 - F0), F1 + a * (f1 - F1), F2 + a * (f2 - F2)
            r0, r1, r2 = Q0 + a * (r0 - Q0), Q1 + a * (r1 - Q1), Q2 + a * (r2 - Q2)
        s[FAVG_SET], s[FAVG], s[FAVG + 1], s[FAVG + 2] = 1.0, f0, f1, f2
        s[RAVG], s[RAVG + 1], s[RAVG + 2] = r0, r1, r2
        nf = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
        nr = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
        if nf > 1e-9 and nr > 1e-9:
            w = 1.0 - g[ACCEL_WEIGHT] * (1.0 - min(max(1.0 - 2.0 * abs(1.0 - nf / nr), 0.0), 1.0))
            s[ACCEL_W] = w
            c = w / (nf * nr)
            ex = (f1 * r2 - f2 * r1) * c
            ey = (f2 * r0 - f0 * r2) * c
    s[ERROR_RP] = math.hypot(ex, ey)
    bx, by, bz = X[0] * ex + Y[0] * ey, X[1] * ex + Y[1] * ey, X[2] * ex + Y[2] * ey
    # 4. yaw error
    ez = 0.0
    source = 0.0
    use_course = True
    if has_mag:
        gm = (g[M0], g[M1], g[M2], g[M3], g[M4], g[M5], g[M6])
        ok, _, _, _ = k.mag_field(s, mag[0], mag[1], mag[2], X, Y, Z, dt, spin, gm, False)
        if ok:
            source = 1.0
            ez = s[k.WEIGHT] * math.sin(s[k.YAW_ERROR])
            use_course = False
        else:
            source = 2.0
            s[MAG_REJECTED] += 1.0
    if use_course:
        course = k.gps_course_at(s, t, g[GPS_SPEED_MIN])
        if not math.isnan(course):
            source = 3.0
            ez = X[0] * math.sin(course) - Y[0] * math.cos(course)
    s[YAW_SOURCE] = source
    s[ERROR_YAW] = abs(ez)
    # 5. PI
    sp = min(max(spin / math.radians(50.0), 1.0), 10.0)
    kp = g[KP_RP] * (sp if g[SPIN_GAIN] >= 0.5 else 1.0)
    kpy = g[KP_YAW] * (sp if g[SPIN_GAIN_YAW] >= 0.5 else 1.0)
    dev = accel_norm - G0
    s[ACCEL_DEV] += dt / (g[ACCEL_TAU] + dt) * (dev * dev - s[ACCEL_DEV])
    gate, half = g[ACCEL_DEV_GATE], g[YAW_SPIN_HALF]
    if gate > 0.0:
        kp /= 1.0 + s[ACCEL_DEV] / (gate * gate)
    turn = 1.0
    if half > 0.0:
        turn += (gx * gx + gy * gy + gz * gz) / (half * half)
        kpy /= turn
    cap = g[YAW_ACC_CAP] * turn
    if cap > 0.0 and kpy * s[ACCEL_DEV] > cap:
        kpy = cap / s[ACCEL_DEV]
    s[OMEGA_P], s[OMEGA_P + 1], s[OMEGA_P + 2] = kp * bx, kp * by, kp * bz
    s[OMEGA_Y], s[OMEGA_Y + 1], s[OMEGA_Y + 2] = kpy * ez * Z[0], kpy * ez * Z[1], kpy * ez * Z[2]
    s[CORR_E], s[CORR_E + 1], s[CORR_E + 2] = kp * ex, kp * ey, kpy * ez
    if spin < SPIN_RATE_LIMIT and not shock_active:
        ki, kiy = g[KI_RP] * dt, g[KI_YAW] * ez * dt
        s[OMEGA_I] = min(max(s[OMEGA_I] + ki * bx + kiy * Z[0], -OMEGA_I_MAX), OMEGA_I_MAX)
        s[OMEGA_I + 1] = min(max(s[OMEGA_I + 1] + ki * by + kiy * Z[1], -OMEGA_I_MAX), OMEGA_I_MAX)
        s[OMEGA_I + 2] = min(max(s[OMEGA_I + 2] + ki * bz + kiy * Z[2], -OMEGA_I_MAX), OMEGA_I_MAX)
    # 6. at rest the gyro reads its bias
    b0, b1, b2 = rest_bias(
        s, REST, t, gyro, -s[OMEGA_I], -s[OMEGA_I + 1], -s[OMEGA_I + 2], accel, k.gps_at(s, t), dt,
        g[REST_GYRO], g[REST_ACC], g[REST_TIME], g[REST_TAU],
    )  # fmt: skip
    s[OMEGA_I] = min(max(-b0, -OMEGA_I_MAX), OMEGA_I_MAX)
    s[OMEGA_I + 1] = min(max(-b1, -OMEGA_I_MAX), OMEGA_I_MAX)
    s[OMEGA_I + 2] = min(max(-b2, -OMEGA_I_MAX), OMEGA_I_MAX)
    k.rows_to_quat(s, ROWS)
    return code


class DcmCompiled(StartedInPython, DcmEstimator):
    """`dcm` with its per-sample update compiled; same gains, presets, outputs and health as
    DcmEstimator (the reference)."""

    KERNELS = Kernels(k.DCM)
    STEP = staticmethod(step)

    def __init__(self, preset: str | None = None, **gains: float) -> None:
        self._compiled_state(SIZE)
        self.s[ROWS : ROWS + 9 : 4] = 1.0  # R = I, q = (1, 0, 0, 0) until the first sample
        super().__init__(preset, **gains)
        self._mag_view = MagView(self.s)

    # the reference's attributes the base class and callers use, kept in the state

    def _reset_correction(self, gyro: tuple[float, float, float]) -> None:
        s = self.s
        s[OMEGA_I : CORR_E + 3] = 0.0
        s[GYRO_PREV : GYRO_PREV + 3] = gyro
        s[FAVG_SET] = 0.0
        s[RAVG : RAVG + 3] = (0.0, 0.0, -G0)
        s[ACCEL_W] = 1.0
        s[ACCEL_DEV] = 0.0
        k.reset_mag(s)
        k.reset_shock(s)
        reset_rest(s, REST)

    def _start(self, sample: ImuSample) -> None:
        """DcmEstimator's initialisation on the kernel state."""
        s = self.s
        R = initial_attitude(sample.accel, sample.mag, self.gains["declination"])
        s[ROWS : ROWS + 9] = np.asarray(R, dtype=float).reshape(-1)
        s[k.Q : k.Q + 4] = matrix_to_quat(R)
        self._reset_correction(vec3(float(v) for v in sample.gyro))
        if self.force_carried:
            s[FAVG_SET], s[FAVG : FAVG + 3] = 1.0, (0.0, 0.0, -float(np.linalg.norm(sample.accel)))
        s[k.VALID] = 1.0

    @property
    def matrix(self) -> npt.NDArray[np.float64]:
        return self.s[ROWS : ROWS + 9].reshape(3, 3).copy()

    def health(self) -> dict[str, HealthValue]:
        s = self.s
        return {
            "reinit_count": self.reinit_count,
            "last_reinit": self.last_reinit,
            "duplicates": self.duplicates,
            "valid": bool(s[k.VALID]),
            "accel_norm": float(s[k.ACCEL_NORM]),
            "renorm_size": float(s[RENORM_SIZE]),
            "renorm_max": float(s[RENORM_MAX]),
            "error_rp": float(s[ERROR_RP]),
            "error_yaw": float(s[ERROR_YAW]),
            "yaw_source": YAW_SOURCES[int(s[YAW_SOURCE])],
            "omega_I": tuple(s[OMEGA_I : OMEGA_I + 3].tolist()),
            "accel_weight": float(s[ACCEL_W]),
            "mag_disturbed": self._mag_view.disturbed,
            "mag_rejected": int(s[MAG_REJECTED]),
            "mag_offset": self._mag_view.offset,
            "shocks": int(s[k.SHOCK_COUNT]),
        }
