"""`kf` at compiled speed: KalmanAttitudeFilter.update_imu, with filterpy's predict and update
(Joseph form) written out, in one numba kernel over a float64 state (kernels.py lays out the
shared slots). KalmanAttitudeFilter, built on filterpy's KalmanFilter, stays the reference; this
equals it to rounding (tests/test_compiled_estimators.py)."""

from __future__ import annotations

import math

import numpy as np

from gcs.core.estimators import kernels as k
from gcs.core.estimators.base import HealthValue
from gcs.core.estimators.compiled import Kernels, MagView, StartedInPython
from gcs.core.estimators.jit import kernel
from gcs.core.estimators.kernels import State
from gcs.core.estimators.kf import (
    _ANGLES,
    _NO_WEIGHT,
    _RATES,
    BIAS_MAX,
    KalmanAttitudeFilter,
    accel_tilt,
    body_turn,
    euler_rates,
    mag_heading,
)
from gcs.core.estimators.magnetic import MAG_WEIGHT_MIN
from gcs.core.estimators.rest import REST_SIZE, reset_rest, rest_bias
from gcs.core.rotation import Vec3, euler_quat
from gcs.core.samples import G0, ImuSample

_G = {g.name: i for i, g in enumerate(KalmanAttitudeFilter.GAINS)}
Q_GAINS = _G["q_roll"]  # q_roll … q_r, then r_roll … r_r: twelve in a row
R_GAINS = _G["r_roll"]
assert [g.name for g in KalmanAttitudeFilter.GAINS[Q_GAINS : R_GAINS + 6]] == [
    f"{p}_{s}" for p in "qr" for s in _ANGLES + _RATES
]
K_Q, DT_REF, EXACT, COS_MIN, GIMBAL_R = (
    _G["k_q"],
    _G["dt_ref"],
    _G["exact_predict"],
    _G["cos_pitch_min"],
    _G["gimbal_r"],
)
ACCEL_TAU, ACCEL_GATE, MAG_DELAY, MAG_TIME_SIGMA, MAG_DT = (
    _G["accel_tau"], _G["accel_gate"], _G["mag_delay"], _G["mag_time_sigma"], _G["mag_dt"],
)  # fmt: skip
BIAS_TAU, BIAS_ACC_TOL, BIAS_HEADING = _G["bias_tau"], _G["bias_acc_tol"], _G["bias_heading"]
YAW_ACC_R = _G["yaw_acc_r"]
REST_GYRO, REST_ACC, REST_TIME, REST_TAU = _G["rest_gyro"], _G["rest_acc"], _G["rest_time"], _G["rest_bias_tau"]
GPS_GAIN, GPS_SPEED_MIN, MAX_GAP, PICK_DT = _G["gps_gain"], _G["gps_speed_min"], _G["max_gap"], _G["pick_dt"]
SHOCK_ACC, GYRO_LIMIT, SHOCK_HOLD = _G["shock_acc"], _G["gyro_limit"], _G["shock_hold"]
M0, M1, M2, M3, M4, M5, M6 = k.mag_gain_slots(_G)

B = k.BASE
X, P = B, B + 6  # x (6), P (6×6)
RATES_PREV, GYRO_PREV, FAVG_SET, FAVG = B + 42, B + 45, B + 48, B + 49
ACCEL_SCALE, MAG_REJECTED, INNOVATION, HEADING_SOURCE = B + 52, B + 53, B + 54, B + 60
BIAS = B + 61  # 3
# work space of one step (no allocation per sample): r and z (6 each), six 6×6 matrices
W_R, W_Z = B + 64, B + 70
W_PHT, W_S, W_SI, W_K, W_IKH, W_T = range(B + 76, B + 76 + 6 * 36, 36)
REST = B + 76 + 6 * 36  # RestBias
ACCEL_DEV = REST + REST_SIZE  # ⟨(|f| − g)²⟩ over accel_tau
SIZE = ACCEL_DEV + 1
#: heading_source labels by code
HEADING_SOURCES = ("none", "mag", "mag_rejected", "gps_course")
_body_turn = kernel(body_turn)


@kernel
def _euler_rates(roll: float, pitch: float, p: float, q: float, r: float, cos_min: float) -> Vec3:
    """kf.euler_rates."""
    sr, cr = math.sin(roll), math.cos(roll)
    cp = math.cos(pitch)
    cp = math.copysign(max(abs(cp), cos_min), cp)
    tp = math.sin(pitch) / cp
    return p + (sr * q + cr * r) * tp, cr * q - sr * r, (sr * q + cr * r) / cp


@kernel
def _mag_heading(mx: float, my: float, mz: float, roll: float, pitch: float, declination: float) -> float:
    """kf.mag_heading; NaN for None."""
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    ly = cr * my - sr * mz
    lz = sr * my + cr * mz
    lx = cp * mx + sp * lz
    if math.hypot(lx, ly) < 1e-9:
        return math.nan
    return k.wrap_pi(declination - math.atan2(ly, lx))


@kernel
def _invert(A: State, inv: State, n: int) -> None:
    """inv[:n, :n] = A[:n, :n]⁻¹ by Gauss-Jordan elimination with partial pivoting (filterpy:
    numpy's LU inverse); A is overwritten."""
    for i in range(n):
        for j in range(n):
            inv[i, j] = 1.0 if i == j else 0.0
    for c in range(n):
        p = c
        for i in range(c + 1, n):
            if abs(A[i, c]) > abs(A[p, c]):
                p = i
        if p != c:
            for j in range(n):
                A[c, j], A[p, j] = A[p, j], A[c, j]
                inv[c, j], inv[p, j] = inv[p, j], inv[c, j]
        d = A[c, c]
        for j in range(n):
            A[c, j] /= d
            inv[c, j] /= d
        for i in range(n):
            if i != c:
                f = A[i, c]
                if f != 0.0:
                    for j in range(n):
                        A[i, j] -= f * A[c, j]
                        inv[i, j] -= f * inv[c, j]


@kernel
def _work(s: State, at: int) -> State:
    """The 6×6 work matrix at slot `at` (a view: no allocation per step)."""
    return k.matrix(s, at, 6, 6)


@kernel
def _update(s: State, skip: int, z: State, r: State) -> None:
    """filterpy KalmanFilter.update(z, R=diag(r), H=I without row `skip`; 6: none): y = z − Hx,
    S = HPHᵀ + R, K = PHᵀS⁻¹, x += Ky, P = (I − KH)P(I − KH)ᵀ + KRKᵀ. y goes to INNOVATION
    (0 for the skipped row). z and r have six rows; the skipped one is not read."""
    m = 6 if skip >= 6 else 5
    x = s[X : X + 6]
    Pm = _work(s, P)
    PHT, S, SI = _work(s, W_PHT), _work(s, W_S), _work(s, W_SI)
    K, IKH, T = _work(s, W_K), _work(s, W_IKH), _work(s, W_T)
    for a in range(m):
        ra = a if a < skip else a + 1
        s[INNOVATION + ra] = z[ra] - x[ra]
        for i in range(6):
            PHT[i, a] = Pm[i, ra]
    if m == 5:
        s[INNOVATION + skip] = 0.0
    for a in range(m):
        ra = a if a < skip else a + 1
        for b in range(m):
            S[a, b] = PHT[ra, b]
        S[a, a] += r[ra]
    _invert(S, SI, m)
    for i in range(6):
        for b in range(m):
            acc = 0.0
            for a in range(m):
                acc += PHT[i, a] * SI[a, b]
            K[i, b] = acc
    for i in range(6):
        acc = 0.0
        for a in range(m):
            acc += K[i, a] * s[INNOVATION + (a if a < skip else a + 1)]
        x[i] += acc
    for i in range(6):
        for j in range(6):
            IKH[i, j] = 1.0 if i == j else 0.0
            T[i, j] = 0.0
    for i in range(6):
        for a in range(m):
            IKH[i, a if a < skip else a + 1] -= K[i, a]
    for i in range(6):
        for l in range(6):
            f = IKH[i, l]
            if f != 0.0:
                for j in range(6):
                    T[i, j] += f * Pm[l, j]
    for i in range(6):
        for j in range(6):
            acc = 0.0
            for l in range(6):
                acc += T[i, l] * IKH[j, l]
            for a in range(m):
                acc += K[i, a] * r[a if a < skip else a + 1] * K[j, a]
            Pm[i, j] = acc


@kernel
def step(s: State, hist: State, g: State, t: float, gyro: State, accel: State, mag: State, has_mag: bool) -> int:
    """KalmanAttitudeFilter.update_imu (hist: unused, the shared signature). Returns the time
    policy's code (kernels.STEP ...); on a re-initialisation code the caller initialises from the sample."""
    fx, fy, fz = accel[0], accel[1], accel[2]
    accel_norm = math.sqrt(fx * fx + fy * fy + fz * fz)
    s[k.ACCEL_NORM] = accel_norm
    code = k.check_time(s, t, g[MAX_GAP])
    if code != k.STEP:
        return code
    dt = t - s[k.T_PREV]
    x = s[X : X + 6]
    Pm = k.matrix(s, P, 6, 6)
    b0, b1, b2 = gyro[0] - s[BIAS], gyro[1] - s[BIAS + 1], gyro[2] - s[BIAS + 2]
    cmin = g[COS_MIN]
    exact = g[EXACT] >= 0.5
    x0, x1, x2, x3, x4 = x[0], x[1], x[2], x[3], x[4]
    if exact:
        a0, a1, a2 = s[GYRO_PREV], s[GYRO_PREV + 1], s[GYRO_PREV + 2]
        c = dt * dt / 12.0
        if dt <= g[PICK_DT]:
            turn = k.quat_exp(b0 * dt, b1 * dt, b2 * dt)
        else:
            turn = k.quat_exp(
                0.5 * (a0 + b0) * dt + c * (a1 * b2 - a2 * b1),
                0.5 * (a1 + b1) * dt + c * (a2 * b0 - a0 * b2),
                0.5 * (a2 + b2) * dt + c * (a0 * b1 - a1 * b0),
            )
        q = k.quat_unit(k.quat_mul(k.euler_quat(x0, x1, x2), turn))
        ang = k.quat_to_euler(q)
        rates = _euler_rates(ang[0], ang[1], b0, b1, b2, cmin)
    else:
        ang = (0.0, 0.0, 0.0)
        rates = _euler_rates(x0 + dt * x3, x1 + dt * x4, b0, b1, b2, cmin)
    u0 = (rates[0] - s[RATES_PREV]) / dt
    u1 = (rates[1] - s[RATES_PREV + 1]) / dt
    u2 = (rates[2] - s[RATES_PREV + 2]) / dt
    # predict: x = Φx + Bu, P = ΦPΦᵀ + Q
    h = 0.5 * dt * dt
    n0, n1, n2 = x[0] + dt * x[3] + h * u0, x[1] + dt * x[4] + h * u1, x[2] + dt * x[5] + h * u2
    x[3], x[4], x[5] = x[3] + dt * u0, x[4] + dt * u1, x[5] + dt * u2
    x[0], x[1], x[2] = n0, n1, n2
    for i in range(3):  # in place: rows 3-5 and then columns 3-5 are read before they change
        for j in range(6):
            Pm[i, j] += dt * Pm[i + 3, j]
    scale = g[K_Q] * dt / g[DT_REF]
    for i in range(6):
        for j in range(3):
            Pm[i, j] += Pm[i, j + 3] * dt
        Pm[i, i] += g[Q_GAINS + i] * scale
    if exact:
        x[0], x[1], x[2], x[3], x[4], x[5] = ang[0], ang[1], ang[2], rates[0], rates[1], rates[2]
    else:
        x[0], x[2] = k.wrap_pi(x[0]), k.wrap_pi(x[2])
        q = k.euler_quat(x[0], x[1], x[2])
    xs0, xs1, xs2 = x[0], x[1], x[2]
    s[GYRO_PREV], s[GYRO_PREV + 1], s[GYRO_PREV + 2] = b0, b1, b2
    s[RATES_PREV], s[RATES_PREV + 1], s[RATES_PREV + 2] = rates
    Rm = k.quat_rows(q)
    an, ae, ad = k.gps_at(s, t)
    kg = g[GPS_GAIN]
    r = s[W_R : W_R + 6]
    for i in range(6):
        r[i] = g[R_GAINS + i]
    spin = math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
    dev = accel_norm - G0
    s[ACCEL_DEV] += dt / (g[ACCEL_TAU] + dt) * (dev * dev - s[ACCEL_DEV])
    if k.shock_update(s, t, accel_norm, spin, g[GYRO_LIMIT], g[SHOCK_ACC], g[SHOCK_HOLD]):
        if s[k.SHOCK_SATURATED] != 0.0:
            s[k.TRUSTED] = 0.0
    if accel_norm > 1e-6 and s[k.SHOCK_ACTIVE] == 0.0:
        fe0 = Rm[0][0] * fx + Rm[0][1] * fy + Rm[0][2] * fz - kg * an
        fe1 = Rm[1][0] * fx + Rm[1][1] * fy + Rm[1][2] * fz - kg * ae
        fe2 = Rm[2][0] * fx + Rm[2][1] * fy + Rm[2][2] * fz - kg * ad
        if s[FAVG_SET] != 0.0 and g[ACCEL_TAU] > 0.0:
            c = dt / (g[ACCEL_TAU] + dt)
            F0, F1, F2 = s[FAVG], s[FAVG + 1], s[FAVG + 2]
            fe0, fe1, fe2 = F0 + c * (fe0 - F0), F1 + c * (fe1 - F1), F2 + c * (fe2 - F2)
        s[FAVG_SET], s[FAVG], s[FAVG + 1], s[FAVG + 2] = 1.0, fe0, fe1, fe2
        fb0 = Rm[0][0] * fe0 + Rm[1][0] * fe1 + Rm[2][0] * fe2
        fb1 = Rm[0][1] * fe0 + Rm[1][1] * fe1 + Rm[2][1] * fe2
        fb2 = Rm[0][2] * fe0 + Rm[1][2] * fe1 + Rm[2][2] * fe2
        roll, pitch = math.atan2(-fb1, -fb2), math.atan2(fb0, math.hypot(fb1, fb2))
        gate = g[ACCEL_GATE]
        dev = abs(math.sqrt(fe0 * fe0 + fe1 * fe1 + fe2 * fe2) - G0)
        s[ACCEL_SCALE] = 1.0 + (dev / gate) ** 2 if gate > 0.0 else 1.0
        r[0] *= s[ACCEL_SCALE]
        r[1] *= s[ACCEL_SCALE]
    else:
        roll, pitch = xs0, xs1
        r[0] = r[1] = _NO_WEIGHT
    if g[GIMBAL_R] >= 0.5:
        sc = 1.0 / max(math.cos(xs1) ** 2, cmin * cmin)
        r[0] *= sc
        r[2] *= sc
        r[3] *= sc
        r[5] *= sc
    # heading (KalmanAttitudeFilter._heading)
    yaw = math.nan
    source = 0.0
    if has_mag:
        mx, my, mz = mag[0], mag[1], mag[2]
        lag = g[MAG_DELAY]
        if lag > 0.0:
            wx, wy, wz = b0, b1, b2  # gyro_prev, already this sample's
            mx, my, mz = mx - lag * (wy * mz - wz * my), my - lag * (wz * mx - wx * mz), mz - lag * (wx * my - wy * mx)
        gm = (g[M0], g[M1], g[M2], g[M3], g[M4], g[M5], g[M6])
        ok, c0, c1, c2 = k.mag_field(s, mx, my, mz, Rm[0], Rm[1], Rm[2], dt, spin, gm, False)
        if ok:
            yaw = _mag_heading(c0, c1, c2, xs0, xs1, g[M6])
        if not math.isnan(yaw):
            source = 1.0
        else:
            s[MAG_REJECTED] += 1.0
    if source == 0.0:
        yaw = k.gps_course_at(s, t, g[GPS_SPEED_MIN])
        if not math.isnan(yaw):
            source = 3.0
        elif has_mag:
            source = 2.0
    s[HEADING_SOURCE] = source
    z0 = xs0 + k.wrap_pi(roll - xs0)
    z = s[W_Z : W_Z + 6]
    z[0], z[1], z[3], z[4], z[5] = z0, pitch, rates[0], rates[1], rates[2]
    skip = 2  # no heading: H without the yaw row
    if not math.isnan(yaw):
        r[2] += (spin * g[MAG_TIME_SIGMA]) ** 2
        if source == 1.0:  # accelerating: the tilt, hence the levelled field, is less sure
            r[2] = max(r[2], g[YAW_ACC_R] * s[ACCEL_DEV])
        if dt < g[MAG_DT]:
            r[2] *= g[MAG_DT] / dt
        if source == 1.0:
            r[2] /= max(s[k.WEIGHT], MAG_WEIGHT_MIN)
        z[2] = xs2 + k.wrap_pi(yaw - xs2)
        skip = 6
    _update(s, skip, z, r)
    q_post = k.euler_quat(x[0], x[1], x[2])  # the updated attitude, once for the three uses below
    tau = g[BIAS_TAU]
    if tau > 0.0 and s[k.SHOCK_ACTIVE] == 0.0 and abs(accel_norm - G0) < g[BIAS_ACC_TOL]:
        d = _body_turn(q, q_post)
        if g[BIAS_HEADING] < 0.5:
            D = Rm[2]
            dd = d[0] * D[0] + d[1] * D[1] + d[2] * D[2]
            d = (d[0] - dd * D[0], d[1] - dd * D[1], d[2] - dd * D[2])
        for i in range(3):
            s[BIAS + i] = min(max(s[BIAS + i] - d[i] / tau, -BIAS_MAX), BIAS_MAX)
    b0, b1, b2 = rest_bias(
        s, REST, t, gyro, s[BIAS], s[BIAS + 1], s[BIAS + 2], accel, k.gps_at(s, t), dt,
        g[REST_GYRO], g[REST_ACC], g[REST_TIME], g[REST_TAU],
    )  # fmt: skip
    s[BIAS] = min(max(b0, -BIAS_MAX), BIAS_MAX)
    s[BIAS + 1] = min(max(b1, -BIAS_MAX), BIAS_MAX)
    s[BIAS + 2] = min(max(b2, -BIAS_MAX), BIAS_MAX)
    if s[FAVG_SET] != 0.0 and g[ACCEL_TAU] > 0.0:
        Rp = k.quat_rows(q_post)
        F0, F1, F2 = s[FAVG], s[FAVG + 1], s[FAVG + 2]
        fs0 = Rm[0][0] * F0 + Rm[1][0] * F1 + Rm[2][0] * F2
        fs1 = Rm[0][1] * F0 + Rm[1][1] * F1 + Rm[2][1] * F2
        fs2 = Rm[0][2] * F0 + Rm[1][2] * F1 + Rm[2][2] * F2
        s[FAVG] = Rp[0][0] * fs0 + Rp[0][1] * fs1 + Rp[0][2] * fs2
        s[FAVG + 1] = Rp[1][0] * fs0 + Rp[1][1] * fs1 + Rp[1][2] * fs2
        s[FAVG + 2] = Rp[2][0] * fs0 + Rp[2][1] * fs1 + Rp[2][2] * fs2
    r0, r2 = k.wrap_pi(x[0]), k.wrap_pi(x[2])
    if r0 != x[0] or r2 != x[2]:  # wrapped: the angles' sines and cosines round differently
        x[0], x[2] = r0, r2
        q_post = k.euler_quat(r0, x[1], r2)
    s[k.Q], s[k.Q + 1], s[k.Q + 2], s[k.Q + 3] = q_post
    return code


class KalmanCompiled(StartedInPython, KalmanAttitudeFilter):
    """`kf` with its per-sample update compiled; same gains, presets, outputs and health as
    KalmanAttitudeFilter (the reference, on filterpy)."""

    KERNELS = Kernels(k.KF)
    STEP = staticmethod(step)

    def __init__(self, preset: str | None = None, **gains: float) -> None:
        self._compiled_state(SIZE)
        super().__init__(preset, **gains)

    def _start(self, sample: ImuSample) -> None:
        """KalmanAttitudeFilter._initialise on the kernel state."""
        s, g = self.s, self.gains
        roll, pitch = accel_tilt(sample.accel)
        k.reset_mag(s)
        k.reset_shock(s)
        reset_rest(s, REST)
        yaw = mag_heading(sample.mag, roll, pitch, g["declination"]) if sample.mag is not None else None
        s[HEADING_SOURCE] = 1.0 if yaw is not None else 0.0
        rates = euler_rates(roll, pitch, sample.gyro, g["cos_pitch_min"])
        s[RATES_PREV : RATES_PREV + 3] = rates
        s[GYRO_PREV : GYRO_PREV + 3] = np.asarray(sample.gyro, float)
        s[FAVG_SET] = s[ACCEL_DEV] = 0.0
        if self.force_carried:
            s[FAVG_SET], s[FAVG : FAVG + 3] = 1.0, (0.0, 0.0, -float(np.linalg.norm(sample.accel)))
        s[BIAS : BIAS + 3] = 0.0
        s[X : X + 6] = (roll, pitch, yaw or 0.0, *rates)
        s[P : P + 36] = np.diag([g[f"q_{a}"] for a in _ANGLES + _RATES]).reshape(-1)
        s[k.Q : k.Q + 4] = euler_quat(roll, pitch, yaw or 0.0)
        s[k.VALID] = 1.0

    @property
    def euler(self) -> tuple[float, float, float]:
        x = self.s[X : X + 3].tolist()
        return x[0], x[1], x[2]

    def health(self) -> dict[str, HealthValue]:
        s = self.s
        view = MagView(s)
        innovation = s[INNOVATION : INNOVATION + 6].tolist()
        diag = s[P : P + 36 : 7].tolist()
        return {
            "reinit_count": self.reinit_count,
            "last_reinit": self.last_reinit,
            "duplicates": self.duplicates,
            "valid": bool(s[k.VALID]),
            "accel_norm": float(s[k.ACCEL_NORM]),
            "heading_source": HEADING_SOURCES[int(s[HEADING_SOURCE])],
            **{f"innovation_{a}": v for a, v in zip(_ANGLES + _RATES, innovation)},
            "accel_scale": float(s[ACCEL_SCALE]),
            "mag_disturbed": view.disturbed,
            "mag_rejected": int(s[MAG_REJECTED]),
            "mag_offset": view.offset,
            "shocks": int(s[k.SHOCK_COUNT]),
            "gyro_bias": (float(s[BIAS]), float(s[BIAS + 1]), float(s[BIAS + 2])),
            **{f"sigma_{a}": math.sqrt(max(v, 0.0)) for a, v in zip(_ANGLES + _RATES, diag)},
        }
