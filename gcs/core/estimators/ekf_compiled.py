"""`ekf` at compiled speed: EkfEstimator's IMU and GPS steps transcribed into numba kernels over a
float64 state (kernels.py lays out the shared slots) and a ring buffer of past velocities.
EkfEstimator stays the readable reference; this equals it to rounding
(tests/test_compiled_estimators.py)."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from gcs.core.estimators import kernels as k
from gcs.core.estimators.base import HealthValue, initial_attitude
from gcs.core.estimators.compiled import Compiled, Kernels, MagView, floats, reinit_reason
from gcs.core.estimators.ekf import MAG_SETTLE_TILT, MAG_TIME_DT, EkfEstimator
from gcs.core.estimators.jit import kernel
from gcs.core.estimators.kernels import State
from gcs.core.estimators.magnetic import MAG_WEIGHT_MIN
from gcs.core.estimators.rest import rest_still
from gcs.core.rotation import Vec3, matrix_to_quat
from gcs.core.samples import G0, GpsSample, ImuSample

_G = {g.name: i for i, g in enumerate(EkfEstimator.GAINS)}
GYRO_NOISE, HEADING_NOISE, BIAS_WALK, ACC_NOISE = (
    _G["gyro_noise"],
    _G["heading_noise"],
    _G["bias_walk"],
    _G["acc_noise"],
)
ACC_GATE, VEL_NOISE, GPS_NOISE, GPS_DELAY = _G["acc_gate"], _G["vel_noise"], _G["gps_noise"], _G["gps_delay"]
GPS_TIMEOUT, MAG_NOISE, REST_GYRO, REST_ACC_G = _G["gps_timeout"], _G["mag_noise"], _G["rest_gyro"], _G["rest_acc"]
MAG_TIME_SIGMA = _G["mag_time_sigma"]
REST_TIME, REST_NOISE, REST_ACC_NOISE, MAX_GAP = _G["rest_time"], _G["rest_noise"], _G["rest_acc_noise"], _G["max_gap"]
SHOCK_ACC, GYRO_LIMIT, SHOCK_HOLD, PICK_DT = _G["shock_acc"], _G["gyro_limit"], _G["shock_hold"], _G["pick_dt"]
M0, M1, M2, M3, M4, M5, M6 = k.mag_gain_slots(_G)

B = k.BASE
V, BIAS, V_OFFSET = B, B + 3, B + 6
GPS_T_FUSED, REST_SINCE, REST_ACC_SET = B + 9, B + 10, B + 11  # rest_still's slots: since, acc set, acc (3)
INITIALISED, HIST_HEAD, HIST_N = B + 15, B + 16, B + 17
# EkfEstimator.stats, in its order (accel_norm is the shared slot)
ACC_INFLATION, VEL_INNOV, GPS_NIS, GPS_AIDED, MAG_NIS, MAG_INNOV_DEG, MAG_REJECTED, AT_REST, DROPPED = range(
    B + 18, B + 27
)
P = B + 27  # 9×9
GYRO_PREV_SET, GYRO_PREV = P + 81, P + 82  # flag, 3: the last sample's gyro (picked samples)
# work space of one step (no allocation per sample): an update's P Hᵀ (9×3), S and S⁻¹ (3×3),
# K (9×3), the correction (9) and the innovation (3)
W_PHT, W_S, W_SI, W_K, W_DX, W_Y = P + 85, P + 112, P + 121, P + 130, P + 157, P + 166
SIZE = P + 169
#: the stats that are counts or flags (ints in the reference's health)
_INT_STATS = ("gps_aided", "mag_rejected", "at_rest", "dropped")
_STATS = (
    ("accel_norm", k.ACCEL_NORM), ("acc_inflation", ACC_INFLATION), ("vel_innov", VEL_INNOV), ("gps_nis", GPS_NIS),
    ("gps_aided", GPS_AIDED), ("mag_nis", MAG_NIS), ("mag_innov_deg", MAG_INNOV_DEG), ("mag_rejected", MAG_REJECTED),
    ("at_rest", AT_REST), ("dropped", DROPPED),
)  # fmt: skip
#: step()'s code when the filter is to be initialised without a re-initialisation reason
INITIALISE = 9


@kernel
def _inv_sym(S: State, out: State, m: int) -> None:
    """ekf._inv_sym: out = S⁻¹ for the symmetric m×m top left of S, m = 1, 2 or 3 (adjugate /
    determinant)."""
    if m == 1:
        out[0, 0] = 1.0 / S[0, 0]
    elif m == 2:
        a, b, d = S[0, 0], S[0, 1], S[1, 1]
        det = a * d - b * b
        out[0, 0], out[0, 1], out[1, 0], out[1, 1] = d / det, -b / det, -b / det, a / det
    else:
        a, b, c, d, e, f = S[0, 0], S[0, 1], S[0, 2], S[1, 1], S[1, 2], S[2, 2]
        A, Bc, C = d * f - e * e, c * e - b * f, b * e - c * d
        D, E, F = a * f - c * c, b * c - a * e, a * d - b * b
        det = a * A + b * Bc + c * C
        out[0, 0], out[0, 1], out[0, 2] = A / det, Bc / det, C / det
        out[1, 0], out[1, 1], out[1, 2] = Bc / det, D / det, E / det
        out[2, 0], out[2, 1], out[2, 2] = C / det, E / det, F / det


@kernel
def _shift_velocity(s: State, d0: float, d1: float, d2: float) -> None:
    s[V] += d0
    s[V + 1] += d1
    s[V + 2] += d2
    s[V_OFFSET] += d0
    s[V_OFFSET + 1] += d1
    s[V_OFFSET + 2] += d2


@kernel
def _work(s: State, at: int, rows: int) -> State:
    """The rows×3 work matrix at slot `at` (a view: no allocation per step)."""
    return k.matrix(s, at, rows, 3)


@kernel
def _update(s: State, PHt: State, S: State, y: State, m: int) -> State:
    """EkfEstimator._update for m measurements (the first m columns of PHt, S's m×m top left; PHt
    not a view of P): K = P Hᵀ S⁻¹, P ← sym(P − K (P Hᵀ)ᵀ), inject K y. Returns S⁻¹."""
    S_inv, K, dx = _work(s, W_SI, 3), _work(s, W_K, 9), s[W_DX : W_DX + 9]
    _inv_sym(S, S_inv, m)
    for i in range(9):
        for j in range(m):
            acc = 0.0
            for l in range(m):
                acc += PHt[i, l] * S_inv[l, j]
            K[i, j] = acc
    Pm = k.matrix(s, P, 9, 9)
    for i in range(9):  # in place: each pair (i, j), (j, i) is read only at its own turn
        for j in range(i, 9):
            a = b = 0.0
            for l in range(m):
                a += K[i, l] * PHt[j, l]
                b += K[j, l] * PHt[i, l]
            Pm[i, j] = Pm[j, i] = 0.5 * ((Pm[i, j] - a) + (Pm[j, i] - b))
    for i in range(9):
        acc = 0.0
        for l in range(m):
            acc += K[i, l] * y[l]
        dx[i] = acc
    q = (s[k.Q], s[k.Q + 1], s[k.Q + 2], s[k.Q + 3])
    q = k.quat_unit(k.quat_mul(k.quat_exp(dx[0], dx[1], dx[2]), q))
    s[k.Q], s[k.Q + 1], s[k.Q + 2], s[k.Q + 3] = q
    _shift_velocity(s, dx[3], dx[4], dx[5])
    s[BIAS] += dx[6]
    s[BIAS + 1] += dx[7]
    s[BIAS + 2] += dx[8]
    return S_inv


@kernel
def _block_update(s: State, lo: int, hi: int, r: float, y: State) -> State:
    """_update with H selecting states lo..hi-1: P Hᵀ = P[:, lo:hi], S = P[lo:hi, lo:hi] + r I."""
    m = hi - lo
    Pm = k.matrix(s, P, 9, 9)
    PHt, S = _work(s, W_PHT, 9), _work(s, W_S, 3)
    for i in range(9):
        for j in range(m):
            PHt[i, j] = Pm[i, lo + j]
    for i in range(m):
        for j in range(m):
            S[i, j] = Pm[lo + i, lo + j]
        S[i, i] += r
    return _update(s, PHt, S, y, m)


@kernel
def _velocity_at(s: State, hist: State, t: float) -> Vec3:
    """EkfEstimator._velocity_at: the velocity at an earlier time t, later corrections applied."""
    ox, oy, oz = s[V_OFFSET], s[V_OFFSET + 1], s[V_OFFSET + 2]
    v0, v1, v2 = s[V] - ox, s[V + 1] - oy, s[V + 2] - oz
    cap = hist.shape[0]
    head, n = int(s[HIST_HEAD]), int(s[HIST_N])
    for i in range(n - 1, -1, -1):
        row = (head + i) % cap
        v0, v1, v2 = hist[row, 1], hist[row, 2], hist[row, 3]
        if hist[row, 0] <= t:
            break
    return v0 + ox, v1 + oy, v2 + oz


@kernel
def step(s: State, hist: State, g: State, t: float, gyro: State, accel: State, mag: State, has_mag: bool) -> int:
    """EkfEstimator.update_imu. Returns the time policy's code (kernels.STEP ...), or INITIALISE;
    on a re-initialisation code or INITIALISE the caller initialises from the sample."""
    g0, g1, g2 = gyro[0], gyro[1], gyro[2]
    a0, a1, a2 = accel[0], accel[1], accel[2]
    if has_mag and not (
        math.isfinite(mag[0]) and math.isfinite(mag[1]) and math.isfinite(mag[2]) and (mag[0] or mag[1] or mag[2])
    ):
        has_mag = False
    if not (
        math.isfinite(g0) and math.isfinite(g1) and math.isfinite(g2)
        and math.isfinite(a0) and math.isfinite(a1) and math.isfinite(a2)
    ):  # fmt: skip
        s[DROPPED] += 1.0
        return k.DUPLICATE
    code = k.check_time(s, t, g[MAX_GAP])
    if code != k.STEP and code != k.DUPLICATE:
        return code
    if s[INITIALISED] == 0.0:
        return INITIALISE
    if code == k.DUPLICATE:
        return code
    dt = t - s[k.T_PREV]
    Pm = k.matrix(s, P, 9, 9)
    spin = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
    a_norm = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    shock = k.shock_update(s, t, a_norm, spin, g[GYRO_LIMIT], g[SHOCK_ACC], g[SHOCK_HOLD])
    # -- _predict
    bx, by, bz = s[BIAS], s[BIAS + 1], s[BIAS + 2]
    w0, w1, w2 = g0 - bx, g1 - by, g2 - bz
    if s[GYRO_PREV_SET] == 0.0 or dt <= g[PICK_DT]:
        t0, t1, t2 = w0 * dt, w1 * dt, w2 * dt
    else:  # picked samples: trapezoid + coning between the last two rates
        p0, p1, p2 = s[GYRO_PREV] - bx, s[GYRO_PREV + 1] - by, s[GYRO_PREV + 2] - bz
        h, c = 0.5 * dt, dt * dt / 12.0
        t0 = (p0 + w0) * h + (p1 * w2 - p2 * w1) * c
        t1 = (p1 + w1) * h + (p2 * w0 - p0 * w2) * c
        t2 = (p2 + w2) * h + (p0 * w1 - p1 * w0) * c
    s[GYRO_PREV_SET], s[GYRO_PREV], s[GYRO_PREV + 1], s[GYRO_PREV + 2] = 1.0, g0, g1, g2
    q = (s[k.Q], s[k.Q + 1], s[k.Q + 2], s[k.Q + 3])
    q = k.quat_unit(k.quat_mul(q, k.quat_exp(t0, t1, t2)))
    s[k.Q], s[k.Q + 1], s[k.Q + 2], s[k.Q + 3] = q
    R = k.quat_rows(q)
    if shock:
        fx, fy, fz = 0.0, 0.0, -G0
    else:
        fx = R[0][0] * a0 + R[0][1] * a1 + R[0][2] * a2
        fy = R[1][0] * a0 + R[1][1] * a1 + R[1][2] * a2
        fz = R[2][0] * a0 + R[2][1] * a1 + R[2][2] * a2
    s[V] = s[V] + fx * dt
    s[V + 1] = s[V + 1] + fy * dt
    s[V + 2] = s[V + 2] + (fz + G0) * dt
    cap = hist.shape[0]
    head, n = int(s[HIST_HEAD]), int(s[HIST_N])
    row = (head + n) % cap
    hist[row, 0] = t
    hist[row, 1] = s[V] - s[V_OFFSET]
    hist[row, 2] = s[V + 1] - s[V_OFFSET + 1]
    hist[row, 3] = s[V + 2] - s[V_OFFSET + 2]
    n += 1
    horizon = t - 2.0 * g[GPS_TIMEOUT]
    while n > 0 and hist[head, 0] < horizon:
        head = (head + 1) % cap
        n -= 1
    s[HIST_HEAD], s[HIST_N] = head, n
    inflation = 1.0 + ((a_norm - G0) / g[ACC_GATE]) ** 2
    s[k.ACCEL_NORM] = a_norm
    s[ACC_INFLATION] = inflation
    # P ← F P Fᵀ with F = I + E, E[θ, b] = −R dt and E[v, θ] = −[R a]× dt = K: only E's 15
    # entries are multiplied (F P = P + E P, then (F P) Fᵀ = F P + (F P) Eᵀ)
    d = (
        (-R[0][0] * dt, -R[0][1] * dt, -R[0][2] * dt),
        (-R[1][0] * dt, -R[1][1] * dt, -R[1][2] * dt),
        (-R[2][0] * dt, -R[2][1] * dt, -R[2][2] * dt),
    )
    K = ((0.0, fz * dt, -fy * dt), (-fz * dt, 0.0, fx * dt), (fy * dt, -fx * dt, 0.0))
    # in place: a column (then a row) is read whole before any of it is written
    for j in range(9):
        p0, p1, p2, p6, p7, p8 = Pm[0, j], Pm[1, j], Pm[2, j], Pm[6, j], Pm[7, j], Pm[8, j]
        for i in range(3):
            Pm[i, j] += d[i][0] * p6 + d[i][1] * p7 + d[i][2] * p8
            Pm[3 + i, j] += K[i][0] * p0 + K[i][1] * p1 + K[i][2] * p2
    for i in range(9):
        f0, f1, f2, f6, f7, f8 = Pm[i, 0], Pm[i, 1], Pm[i, 2], Pm[i, 6], Pm[i, 7], Pm[i, 8]
        for j in range(3):
            Pm[i, j] += f6 * d[j][0] + f7 * d[j][1] + f8 * d[j][2]
            Pm[i, 3 + j] += f0 * K[j][0] + f1 * K[j][1] + f2 * K[j][2]
    sa = g[ACC_NOISE] * inflation
    qg, qh = g[GYRO_NOISE] ** 2 * dt, g[HEADING_NOISE] ** 2 * dt
    qa, qb = sa * sa * dt, g[BIAS_WALK] ** 2 * dt
    Pm[0, 0] += qg
    Pm[1, 1] += qg
    Pm[2, 2] += qh
    for i in range(3, 6):
        Pm[i, i] += qa
    for i in range(6, 9):
        Pm[i, i] += qb
    # -- saturated gyro
    if s[k.SHOCK_SATURATED] != 0.0:
        qs = (spin * dt) ** 2
        Pm[0, 0] += qs
        Pm[1, 1] += qs
        Pm[2, 2] += qs
        s[k.TRUSTED] = 0.0
    aided = t - s[GPS_T_FUSED] <= g[GPS_TIMEOUT]
    s[GPS_AIDED] = 1.0 if aided else 0.0
    if shock:
        s[REST_ACC_SET] = 0.0
    else:
        # -- _at_rest (rest.RestTest on REST_SINCE.., laid out as its kernel's slots)
        wx, wy, wz = g0 - s[BIAS], g1 - s[BIAS + 1], g2 - s[BIAS + 2]
        rest = rest_still(s, REST_SINCE, t, wx, wy, wz, a0, a1, a2, True, g[REST_GYRO], g[REST_ACC_G], g[REST_TIME])
        s[AT_REST] = 1.0 if rest else 0.0
        if s[AT_REST] != 0.0:
            # zero rate: y = gyro − b, H = [0, 0, I]
            y = s[W_Y : W_Y + 3]
            y[0], y[1], y[2] = g0 - s[BIAS], g1 - s[BIAS + 1], g2 - s[BIAS + 2]
            _block_update(s, 6, 9, g[REST_NOISE] ** 2 / dt, y)
            if not aided:
                # gravity: y = (R a + g)_NE, P Hᵀ = P[:, θ] Uᵀ with U the non-zero rows of [−g]×
                r = g[REST_ACC_NOISE] ** 2 / dt
                PHt, S = _work(s, W_PHT, 9), _work(s, W_S, 3)
                for i in range(9):
                    PHt[i, 0] = Pm[i, 1] * G0
                    PHt[i, 1] = -G0 * Pm[i, 0]
                for j in range(2):
                    S[0, j] = G0 * PHt[1, j]
                    S[1, j] = -G0 * PHt[0, j]
                S[0, 0] += r
                S[1, 1] += r
                R2 = k.quat_rows((s[k.Q], s[k.Q + 1], s[k.Q + 2], s[k.Q + 3]))
                y[0] = R2[0][0] * a0 + R2[0][1] * a1 + R2[0][2] * a2
                y[1] = R2[1][0] * a0 + R2[1][1] * a1 + R2[1][2] * a2
                _update(s, PHt, S, y, 2)
    # -- _update_velocity_prior
    axes = 1 if aided else 3
    yv = s[W_Y : W_Y + 3]
    for i in range(axes):
        yv[i] = -s[V + 3 - axes + i]
    if axes == 3:
        s[VEL_INNOV] = math.sqrt(yv[0] * yv[0] + yv[1] * yv[1] + yv[2] * yv[2])
    _block_update(s, 6 - axes, 6, g[VEL_NOISE] ** 2 / dt, yv)
    # -- _update_heading
    if has_mag:
        q = (s[k.Q], s[k.Q + 1], s[k.Q + 2], s[k.Q + 3])
        R = k.quat_rows(q)
        bx, by, bz = s[BIAS], s[BIAS + 1], s[BIAS + 2]
        settling = Pm[0, 0] + Pm[1, 1] > MAG_SETTLE_TILT**2
        gm = (g[M0], g[M1], g[M2], g[M3], g[M4], g[M5], g[M6])
        turn = math.sqrt((g0 - bx) ** 2 + (g1 - by) ** 2 + (g2 - bz) ** 2)
        ok, c0, c1, c2 = k.mag_field(s, mag[0], mag[1], mag[2], R[0], R[1], R[2], dt, turn, gm, settling)
        if not ok:
            s[MAG_REJECTED] += 1.0
        else:
            n0 = R[0][0] * c0 + R[0][1] * c1 + R[0][2] * c2
            n1 = R[1][0] * c0 + R[1][1] * c1 + R[1][2] * c2
            m_h = math.hypot(n0, n1)
            m_norm = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
            if m_h < 1e-3 * m_norm:
                s[MAG_REJECTED] += 1.0
            else:
                sigma = g[MAG_NOISE] * m_norm / m_h
                tt = turn * g[MAG_TIME_SIGMA]
                r = (sigma * sigma / dt + tt * tt * max(1.0, MAG_TIME_DT / dt)) / max(s[k.WEIGHT], MAG_WEIGHT_MIN)
                y = s[k.YAW_ERROR]
                p = s[W_DX : W_DX + 9]
                for i in range(9):
                    p[i] = Pm[i, 2]
                sv = p[2] + r
                kk = p[2] / sv
                for j in range(9):
                    Pm[2, j] -= kk * p[j]
                for i in range(9):
                    Pm[i, 2] -= kk * p[i]
                Pm[2, 2] += sv * (kk * kk)
                s[MAG_NIS] = y * y / sv
                s[MAG_INNOV_DEG] = math.degrees(y)
                q = k.quat_unit(k.quat_mul(k.quat_exp(0.0, 0.0, kk * y), q))
                s[k.Q], s[k.Q + 1], s[k.Q + 2], s[k.Q + 3] = q
    return code


@kernel
def gps_step(s: State, hist: State, g: State, t: float, vn: float, ve: float) -> None:
    """EkfEstimator.update_gps after its checks: fuse the horizontal velocity (vn, ve) at t."""
    now = s[k.T]
    if math.isnan(now) or now - s[GPS_T_FUSED] > g[GPS_TIMEOUT]:
        _shift_velocity(s, vn - s[V], ve - s[V + 1], 0.0)
        Pm = k.matrix(s, P, 9, 9)
        Pm[3:5, :] = 0.0
        Pm[:, 3:5] = 0.0
        Pm[3, 3] = Pm[4, 4] = g[GPS_NOISE] ** 2
    else:
        v0, v1, _ = _velocity_at(s, hist, t - g[GPS_DELAY])
        y = s[W_Y : W_Y + 3]
        y[0], y[1] = vn - v0, ve - v1
        S_inv = _block_update(s, 3, 5, g[GPS_NOISE] ** 2, y)
        a, b, d = S_inv[0, 0], S_inv[0, 1], S_inv[1, 1]
        s[GPS_NIS] = a * y[0] * y[0] + 2.0 * b * y[0] * y[1] + d * y[1] * y[1]
        s[VEL_INNOV] = math.hypot(y[0], y[1])
    s[GPS_T_FUSED] = t


@kernel
def gps_input(
    s: State, hist: State, g: State, t: float, fix_type: float, vel: State, has_vel: bool, speed: float, course: float
) -> None:
    """EkfEstimator.update_gps: its checks, then gps_step (speed and course: unused, the shared signature)."""
    if fix_type < 3 or not has_vel or s[INITIALISED] == 0.0 or t <= s[GPS_T_FUSED]:
        return
    gps_step(s, hist, g, t, vel[0], vel[1])


class EkfCompiled(Compiled, EkfEstimator):
    """`ekf` with its IMU and GPS steps compiled; same gains, presets, outputs and health as
    EkfEstimator (the reference)."""

    KERNELS = Kernels(k.EKF, INITIALISED, HIST_N)
    STEP = staticmethod(step)

    def __init__(self, preset: str | None = None, **gains: float) -> None:
        self._compiled_state(SIZE)
        self.s[GPS_T_FUSED] = self.s[REST_SINCE] = -math.inf
        self.hist = np.zeros((1024, 4))
        super().__init__(preset, **gains)

    @property
    def initialised(self) -> bool:
        return bool(self.s[INITIALISED])

    @initialised.setter
    def initialised(self, value: bool) -> None:
        self.s[INITIALISED] = float(value)

    @property
    def P(self) -> npt.NDArray[np.float64]:
        return self.s[P : P + 81].reshape(9, 9)

    @P.setter
    def P(self, value: npt.NDArray[np.float64]) -> None:
        self.s[P : P + 81] = np.asarray(value, dtype=float).reshape(-1)

    @property
    def b(self) -> tuple[float, float, float]:
        b = self.s[BIAS : BIAS + 3].tolist()
        return b[0], b[1], b[2]

    @b.setter
    def b(self, value: tuple[float, float, float]) -> None:
        self.s[BIAS : BIAS + 3] = value

    def _after_step(self, code: int, sample: ImuSample) -> bool:
        s, mag = self.s, sample.mag
        if code == k.STEP:
            return True
        if code == k.DUPLICATE:
            return bool(s[INITIALISED])
        if code != INITIALISE:
            self.last_reinit = reinit_reason(s, code, self.gains["max_gap"])
        accel = np.asarray(sample.accel, float).tolist()
        m = None if mag is None else np.asarray(mag, float).tolist()
        if m is not None and not (all(map(math.isfinite, m)) and any(m)):
            m = None
        return self._start(sample.t, sample.gyro, accel, m)

    def _start(self, t: float, gyro: npt.ArrayLike, accel: list[float], mag: list[float] | None) -> bool:
        """EkfEstimator._initialise on the kernel state."""
        if accel[0] * accel[0] + accel[1] * accel[1] + accel[2] * accel[2] < 1e-6:
            return False
        force = self._start_force(t, gyro, accel, mag is not None)
        if force is None:
            self.initialised = False
            return False
        s, g = self.s, self.gains
        R = initial_attitude(force, None if mag is None else np.array(mag), g["declination"])
        s[k.Q : k.Q + 4] = matrix_to_quat(R)
        s[V : V + 3] = 0.0
        s[GYRO_PREV_SET] = 0.0
        s[V_OFFSET : V_OFFSET + 3] = 0.0
        s[HIST_HEAD] = s[HIST_N] = 0.0
        s[GPS_T_FUSED] = -math.inf
        s[GPS_AIDED] = 0.0
        tilt_var = math.radians(5.0) ** 2
        heading_var = math.radians(20.0 if mag is not None else 180.0) ** 2
        self.P = np.diag([tilt_var, tilt_var, heading_var] + [g["vel_noise"] ** 2] * 3 + [g["bias_init"] ** 2] * 3)
        k.reset_mag(s)
        k.reset_shock(s)
        s[INITIALISED] = 1.0
        return True

    def _grow(self) -> None:
        cap = len(self.hist)
        head, n = int(self.s[HIST_HEAD]), int(self.s[HIST_N])
        rows = (head + np.arange(n)) % cap
        bigger = np.zeros((2 * cap, 4))
        bigger[:n] = self.hist[rows]
        self.hist = bigger
        self.s[HIST_HEAD] = 0.0

    def update_gps(self, sample: GpsSample) -> None:
        vel = self._no_mag if sample.vel_ned is None else floats(sample.vel_ned)
        gps_input(
            self.s, self.hist, self.gain_vector(), sample.t, sample.fix_type, vel, sample.vel_ned is not None,
            sample.ground_speed, sample.course,
        )  # fmt: skip

    def health(self) -> dict[str, HealthValue]:
        s = self.s
        h: dict[str, HealthValue] = {
            "reinit_count": self.reinit_count,
            "last_reinit": self.last_reinit,
            "duplicates": self.duplicates,
        }
        for name, slot in _STATS:
            h[name] = int(s[slot]) if name in _INT_STATS else float(s[slot])
        bias = s[BIAS : BIAS + 3].tolist()
        h.update(bias_x=bias[0], bias_y=bias[1], bias_z=bias[2])
        view = MagView(s)
        h.update(mag_disturbed=view.disturbed, mag_offset=view.offset, mag_relearned=view.relearned)
        h.update(mag_offsets_learned=view.offsets_learned, shocks=int(s[k.SHOCK_COUNT]))
        h["tilt_sigma_deg"] = math.degrees(math.sqrt(max(s[P] + s[P + 10], 0.0)))
        h["heading_sigma_deg"] = math.degrees(math.sqrt(max(s[P + 20], 0.0)))
        return h
