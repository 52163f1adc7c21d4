"""The linear Kalman attitude filter KF-A of seed 004 (Mendoza Robles 2022, §5.2.2 / §5.3.2),
fed raw IMU instead of PX4's own attitude."""

from __future__ import annotations

import functools
import math
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from gcs.core.estimators.base import (
    COMMON_GAINS,
    GPS_GAINS,
    PICK_GAINS,
    SHOCK_GAINS,
    AttitudeEstimator,
    GpsAcceleration,
    HealthValue,
    Shock,
)
from gcs.core.estimators.magnetic import MAG_GAINS, MAG_OFF, MAG_WEIGHT_MIN, MagneticHeading
from gcs.core.estimators.rest import REST_GAINS, REST_OFF, RestBias
from gcs.core.gains import Gain
from gcs.core.rotation import (
    Rows,
    Vec3,
    VectorLike,
    euler_quat,
    euler_to_quat,
    quat_exp,
    quat_mul,
    quat_rows,
    quat_to_euler,
    quat_to_matrix,
    quat_unit,
    vec3,
    wrap_pi,
)
from gcs.core.samples import G0, GpsSample, ImuSample

if TYPE_CHECKING:
    from filterpy.kalman import KalmanFilter

_ANGLES = ("roll", "pitch", "yaw")
_RATES = ("p", "q", "r")
#: Seed 004 Q (5.35; "reference" diagonal, per thesis step) and R (5.37), in state order.
SEED004_Q = (0.0259, 0.0257, 0.4051, 0.4047, 0.1952, 0.1940)
SEED004_R = (0.0202, 0.0842, 0.0066, 0.0006, 0.0025, 0.0034)
_Q_NAMES = tuple(f"q_{s}" for s in _ANGLES + _RATES)
_R_NAMES = tuple(f"r_{s}" for s in _ANGLES + _RATES)
_DIAG5, _DIAG6 = np.diag_indices(5), np.diag_indices(6)
#: Measurement rows without a heading: roll, pitch and the three rates.
_ROWS5 = [0, 1, 3, 4, 5]
#: Largest gyro bias learned, per axis (rad/s; dcm's OMEGA_I_MAX).
BIAS_MAX = 0.1
#: Measurement noise (rad²) of a tilt row that carries no information (a shock, a zero vector).
_NO_WEIGHT = 1e6


def accel_tilt(
    f: VectorLike, a_ned: VectorLike = (0.0, 0.0, 0.0), yaw: float = 0.0, roll: float = 0.0, pitch: float = 0.0
) -> tuple[float, float]:
    """Roll and pitch (rad) that make the specific force f (sensor frame) point "up" (-z NED).

    a_ned, the vehicle's acceleration from GPS, is first removed: f_g = f - Rᵀ a_ned with R from
    the current estimate (roll, pitch, yaw), leaving the gravity-only specific force. Then
    roll = atan2(-f_y, -f_z), pitch = atan2(f_x, √(f_y² + f_z²)) — valid in any right-handed frame.
    """
    fx, fy, fz = (float(v) for v in f)
    if any(a_ned):
        R = quat_to_matrix(euler_to_quat(roll, pitch, yaw))
        ab = R.T @ np.asarray(a_ned, dtype=float)
        fx, fy, fz = fx - ab[0], fy - ab[1], fz - ab[2]
    return math.atan2(-fy, -fz), math.atan2(fx, math.hypot(fy, fz))


def mag_heading(m: VectorLike, roll: float, pitch: float, declination: float) -> float | None:
    """True heading (rad) from the tilt-compensated field: level it by Ry(pitch)·Rx(roll), then
    yaw = declination - atan2(m_level_y, m_level_x). None when the horizontal field vanishes."""
    mx, my, mz = (float(v) for v in m)
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    ly = cr * my - sr * mz
    lz = sr * my + cr * mz
    lx = cp * mx + sp * lz
    if math.hypot(lx, ly) < 1e-9:
        return None
    return wrap_pi(declination - math.atan2(ly, lx))


def body_turn(q0: VectorLike, q1: VectorLike) -> Vec3:
    """The rotation vector δ (rad, body frame) with q1 = q0 ⊗ exp(δ/2): 2·vec(q0⁻¹ ⊗ q1), the
    sign of q0⁻¹ ⊗ q1 taken so its w is not negative (small-angle form)."""
    a0, a1, a2, a3 = q0
    b0, b1, b2, b3 = q1
    w = a0 * b0 + a1 * b1 + a2 * b2 + a3 * b3
    x = a0 * b1 - a1 * b0 - a2 * b3 + a3 * b2
    y = a0 * b2 + a1 * b3 - a2 * b0 - a3 * b1
    z = a0 * b3 - a1 * b2 + a2 * b1 - a3 * b0
    k = -2.0 if w < 0.0 else 2.0
    return k * x, k * y, k * z


def euler_rates(roll: float, pitch: float, gyro: VectorLike, cos_min: float = 1e-6) -> tuple[float, float, float]:
    """Body rates → Z-Y-X Euler-angle rates, seed 004 eq. (4.9). cos(pitch) is floored at cos_min
    (keeping its sign), which bounds the map near the Euler singularity at pitch ±90°."""
    p, q, r = (float(v) for v in gyro)
    sr, cr = math.sin(roll), math.cos(roll)
    cp = math.cos(pitch)
    cp = math.copysign(max(abs(cp), cos_min), cp)
    tp = math.sin(pitch) / cp
    return p + (sr * q + cr * r) * tp, cr * q - sr * r, (sr * q + cr * r) / cp


class KalmanAttitudeFilter(AttitudeEstimator):
    """KF-A: linear Kalman filter on Euler angles and their rates (seed 004, §5.2.2).

    x = [φ θ ψ φ̇ θ̇ ψ̇]; x⁻ = Φx + Bu, Φ = [[I, Δt·I], [0, I]], B = [[Δt²/2·I], [Δt·I]] (5.28)-(5.29), u the
    Euler-angle acceleration from successive gyro samples; z = accelerometer tilt, magnetometer (or GPS
    course) heading and the gyro mapped to Euler rates (4.9), H = I; Q(Δt) = k_q·diag(q)·Δt/dt_ref. Fed raw
    IMU instead of PX4's estimate. Presets `telemetry` (default, robustness terms on) and `seed004`.
    Derivation, deviations from seed 004, robustness terms, gains: docs/estimators/kf.md
    """

    name = "kf"
    GAINS = (
        (
            *(
                Gain(
                    f"q_{s}",
                    v,
                    0.0,
                    100.0,
                    "rad²" if s in _ANGLES else "rad²/s²",
                    f"process noise of {s} per dt_ref step",
                )
                for s, v in zip(_ANGLES + _RATES, SEED004_Q)
            ),
            *(
                Gain(f"r_{s}", v, 1e-8, 100.0, "rad²" if s in _ANGLES else "rad²/s²", f"measurement noise of {s}")
                for s, v in zip(_ANGLES + _RATES, SEED004_R)
            ),
            Gain("k_q", 0.03, 0.0, 1000.0, "", "scale of the process noise Q (thesis k_q)"),
            Gain("dt_ref", 0.004, 1e-4, 1.0, "s", "the step the q_* values are given per (thesis: 4 ms)"),
            Gain(
                "exact_predict", 1.0, 0.0, 1.0, "", "1 = predict the angles by turning the attitude by the gyro exactly"
            ),
            Gain("cos_pitch_min", 0.1, 1e-6, 1.0, "", "floor of |cos pitch| in the gyro → Euler-rate map (4.9)"),
            Gain("gimbal_r", 1.0, 0.0, 1.0, "", "1 = roll, yaw, p, r measurement noise × 1/cos²(pitch)"),
            Gain("accel_tau", 1.0, 0.0, 10.0, "s", "earth-frame average of the specific force for the tilt"),
            Gain("accel_gate", 1.0, 0.0, 100.0, "m/s²", "tilt noise × (1 + (||f_avg| − g| / gate)²); 0 = off"),
            Gain(
                "mag_delay", 0.0, 0.0, 0.05, "s", "how much older the field sample is than the gyro's (turned forward)"
            ),
            Gain(
                "mag_time_sigma", 0.2, 0.0, 1.0, "s", "timing uncertainty of the field sample: yaw noise + (|ω|·σ_t)²"
            ),
            Gain("mag_dt", 0.02, 0.0, 1.0, "s", "step the yaw noise is given per: faster steps get it × mag_dt/Δt"),
            Gain(
                "bias_tau",
                20.0,
                0.0,
                1000.0,
                "s",
                "time constant of the gyro bias learned from the corrections; 0 = off",
            ),
            Gain(
                "bias_heading",
                0.0,
                0.0,
                1.0,
                "",
                "1 = heading corrections teach the bias too (0: tilt corrections only)",
            ),
            Gain("bias_acc_tol", 0.5, 0.0, 1000.0, "m/s²", "the bias is learned only while ||f| - g| is below this"),
            Gain(
                "yaw_acc_r",
                0.05,
                0.0,
                100.0,
                "rad²/(m/s²)²",
                "field heading noise at least this × mean(|f| - g)² (dcm's yaw_acc_cap); 0 = off",
            ),
        )
        + MAG_GAINS
        + REST_GAINS
        + PICK_GAINS
        + SHOCK_GAINS
        + GPS_GAINS
        + COMMON_GAINS
    )
    _THESIS = {
        "exact_predict": 0.0,
        "cos_pitch_min": 1e-6,
        "gimbal_r": 0.0,
        "accel_tau": 0.0,
        "accel_gate": 0.0,
        **MAG_OFF,
        "mag_time_sigma": 0.0,
        "mag_dt": 0.0,
        "bias_tau": 0.0,
        "yaw_acc_r": 0.0,
        **REST_OFF,
    }
    PRESETS = {"seed004": _THESIS, "telemetry": {"q_roll": 2.59e-6, "q_pitch": 2.57e-6, "q_yaw": 4.051e-5}}
    DEFAULT_PRESET = "telemetry"

    def __init__(self, preset: str | None = None, **gains: float) -> None:
        super().__init__(preset, **gains)
        self.rates_prev = (0.0, 0.0, 0.0)
        self.gyro_prev = (0.0, 0.0, 0.0)
        self.bias = (0.0, 0.0, 0.0)  # gyro bias (rad/s, sensor frame), learned from the corrections
        self.f_avg: tuple[float, float, float] | None = None
        self.gps = GpsAcceleration()
        self.mag = MagneticHeading()
        self.shock = Shock()
        self.rest = RestBias()
        self.valid = False
        self.accel_norm = 0.0
        self.accel_scale = 1.0
        self.accel_dev = 0.0  # ⟨(|f| − g)²⟩ over accel_tau (m²/s⁴)
        self.mag_rejected = 0
        self.innovation = np.zeros(6)
        self.heading_source = "none"
        # filterpy inputs reused every sample (written in place; filterpy keeps none of them)
        self._F, self._B, self._Q = np.eye(6), np.zeros((6, 3)), np.zeros((6, 6))
        self._dt: float | None = None
        self._q_key: tuple[float, ...] | None = None
        self._u = np.zeros((3, 1))
        self._H6, self._H5 = np.eye(6), np.eye(6)[_ROWS5]
        self._R6, self._R5 = np.zeros((6, 6)), np.zeros((5, 5))
        self._z6, self._z5 = np.zeros((6, 1)), np.zeros((5, 1))

    @functools.cached_property
    def kf(self) -> KalmanFilter:
        """filterpy's filter, made on first use: filterpy imports scipy.stats (~1 s at every start),
        which the compiled path (the same class's gains and outputs, not this filter) never needs."""
        from filterpy.kalman import KalmanFilter  # noqa: PLC0415

        return KalmanFilter(dim_x=6, dim_z=6, dim_u=3)

    def _q(self, dt: float) -> npt.NDArray[np.float64]:
        g = self.gains
        scale = g["k_q"] * dt / g["dt_ref"]
        return np.diag([g[f"q_{s}"] * scale for s in _ANGLES + _RATES])

    def _r(self) -> npt.NDArray[np.float64]:
        return np.diag([self.gains[f"r_{s}"] for s in _ANGLES + _RATES])

    def update_gps(self, sample: GpsSample) -> None:
        self.gps.update(sample)

    def _heading(self, sample: ImuSample, roll: float, pitch: float, Rm: Rows, dt: float, spin: float) -> float | None:
        g = self.gains
        if sample.mag is not None:
            mx, my, mz = map(float, sample.mag)
            lag = g["mag_delay"]
            if lag > 0.0:  # a field fixed in the earth frame turns as ṁ = −ω × m in the sensor
                wx, wy, wz = self.gyro_prev
                mx, my, mz = (
                    mx - lag * (wy * mz - wz * my),
                    my - lag * (wz * mx - wx * mz),
                    mz - lag * (wx * my - wy * mx),
                )
            mc = self.mag.field((mx, my, mz), Rm, dt, spin, g.values)
            psi = mag_heading(mc, roll, pitch, g["declination"]) if mc is not None else None
            if psi is not None:
                self.heading_source = "mag"
                return psi
            self.mag_rejected += 1
        course = self.gps.course_at(sample.t, g["gps_speed_min"])
        if course is not None:
            self.heading_source = "gps_course"
        elif sample.mag is not None:
            self.heading_source = "mag_rejected"
        else:
            self.heading_source = "none"
        return course

    def _initialise(self, sample: ImuSample) -> None:
        g = self.gains
        roll, pitch = accel_tilt(sample.accel)
        self.mag = MagneticHeading()
        self.shock = Shock()
        self.rest = RestBias()
        yaw = mag_heading(sample.mag, roll, pitch, g["declination"]) if sample.mag is not None else None
        self.heading_source = "mag" if yaw is not None else "none"
        self.rates_prev = euler_rates(roll, pitch, sample.gyro, g["cos_pitch_min"])
        self.gyro_prev = vec3(float(v) for v in sample.gyro)
        self.bias = (0.0, 0.0, 0.0)
        # after a wait for a field the average starts at the carried force, not at the next (jolted) sample
        self.f_avg = (0.0, 0.0, -float(np.linalg.norm(sample.accel))) if self.force_carried else None
        self.accel_dev = 0.0
        self.kf.x = np.array([[roll], [pitch], [yaw or 0.0], *([v] for v in self.rates_prev)])
        self.kf.P = np.diag([g[f"q_{s}"] for s in _ANGLES + _RATES])
        self.valid = True

    def update_imu(self, sample: ImuSample) -> bool:
        # The per-sample path works on plain floats and reuses preallocated filterpy inputs
        # (F, B, Q, u, z, R, H): it gives the same numbers as building them anew each sample.
        fx, fy, fz = map(float, sample.accel)
        self.accel_norm = math.sqrt(fx * fx + fy * fy + fz * fz)
        dt = self._check_time(sample.t)
        if dt is None:
            if self.accel_norm < 1e-6:  # cannot level on a zero vector: wait for a usable sample
                self.t = None
                return self.valid
            force = self._start_force(sample.t, sample.gyro, sample.accel, sample.mag is not None)
            if force is None:  # no heading yet: wait for a field
                self.t = None
                self.reinit_count -= 1
                return self.valid
            self._initialise(replace(sample, accel=force))
            return True
        if dt == 0.0:
            return self.valid
        g = self.gains.values  # the current dict (apply_preset replaces it): plain lookups
        kf = self.kf
        if dt != self._dt:  # Φ and B depend on Δt only; written in place
            F, B = self._F, self._B
            F[0, 3] = F[1, 4] = F[2, 5] = dt
            B[0, 0] = B[1, 1] = B[2, 2] = 0.5 * dt * dt
            B[3, 0] = B[4, 1] = B[5, 2] = dt
            self._dt = dt
        kf.F, kf.B = self._F, self._B
        q_key = (dt, g["k_q"], g["dt_ref"], *(g[k] for k in _Q_NAMES))
        if q_key != self._q_key:  # Q(Δt) = k_q·diag(q)·Δt/dt_ref, rebuilt only when an input changes
            scale = q_key[1] * dt / q_key[2]
            self._Q[_DIAG6] = [v * scale for v in q_key[3:]]
            self._q_key = q_key
        kf.Q = self._Q
        b = self.bias
        gx, gy, gz = map(float, sample.gyro)
        gyro = (gx - b[0], gy - b[1], gz - b[2])
        cmin = g["cos_pitch_min"]
        exact = g["exact_predict"] >= 0.5
        x0 = kf.x[:, 0].tolist()
        if exact:
            # the mean: the attitude turned by the trapezoid of two gyro samples, exactly
            # with the rate varying linearly between them, plus the second-order coning term
            # (ω₀ × ω₁)·dt²/12 (Bortz), which matters at telemetry rates in fast rotation
            # (picked samples, dt > pick_dt); a log's interval means turn by the sample alone
            (a0, a1, a2), (b0, b1, b2) = self.gyro_prev, gyro
            c = dt * dt / 12.0
            if dt <= g["pick_dt"]:
                turn = quat_exp(b0 * dt, b1 * dt, b2 * dt)
            else:
                turn = quat_exp(
                    0.5 * (a0 + b0) * dt + c * (a1 * b2 - a2 * b1),
                    0.5 * (a1 + b1) * dt + c * (a2 * b0 - a0 * b2),
                    0.5 * (a2 + b2) * dt + c * (a0 * b1 - a1 * b0),
                )
            q = quat_unit(quat_mul(euler_quat(x0[0], x0[1], x0[2]), turn))
            ang = quat_to_euler(q)
            rates = euler_rates(ang[0], ang[1], gyro, cmin)
        else:
            # Euler rates of this gyro sample at the attitude predicted by the current rates
            rates = euler_rates(x0[0] + dt * x0[3], x0[1] + dt * x0[4], gyro, cmin)
        r0 = self.rates_prev
        u = self._u
        u[0, 0], u[1, 0], u[2, 0] = (rates[0] - r0[0]) / dt, (rates[1] - r0[1]) / dt, (rates[2] - r0[2]) / dt
        kf.predict(u=u)  # column u: filterpy broadcasts a 1-D one
        if exact:  # P as Φ P Φᵀ + Q; the mean from the exact rotation
            x = [*ang, *rates]
            kf.x[:, 0] = x
            kf.x_prior = kf.x.copy()
        else:
            x = kf.x[:, 0].tolist()
            x[0], x[2] = wrap_pi(x[0]), wrap_pi(x[2])
            kf.x[0, 0], kf.x[2, 0] = x[0], x[2]
            q = euler_quat(x[0], x[1], x[2])
        self.gyro_prev = gyro
        self.rates_prev = rates
        Rm = quat_rows(q)
        # tilt: gravity-only specific force in the earth frame, averaged, back in the sensor frame
        a = self.gps.at(sample.t)
        k = g["gps_gain"]
        r = [g[n] for n in _R_NAMES]
        spin = math.sqrt(gyro[0] ** 2 + gyro[1] ** 2 + gyro[2] ** 2)
        dev = self.accel_norm - G0
        self.accel_dev += dt / (g["accel_tau"] + dt) * (dev * dev - self.accel_dev)
        if self.shock.update(sample.t, self.accel_norm, spin, g) and self.shock.saturated:
            self.mag.distrust_heading()
        if self.accel_norm > 1e-6 and not self.shock.active:
            fe = vec3(Rm[i][0] * fx + Rm[i][1] * fy + Rm[i][2] * fz - k * a[i] for i in range(3))
            if self.f_avg is not None and g["accel_tau"] > 0.0:
                c = dt / (g["accel_tau"] + dt)
                fe = vec3(F + c * (f - F) for F, f in zip(self.f_avg, fe))
            self.f_avg = fe
            fb = tuple(Rm[0][i] * fe[0] + Rm[1][i] * fe[1] + Rm[2][i] * fe[2] for i in range(3))
            roll, pitch = math.atan2(-fb[1], -fb[2]), math.atan2(fb[0], math.hypot(fb[1], fb[2]))
            gate = g["accel_gate"]
            dev = abs(math.sqrt(fe[0] * fe[0] + fe[1] * fe[1] + fe[2] * fe[2]) - G0)
            self.accel_scale = 1.0 + (dev / gate) ** 2 if gate > 0.0 else 1.0
            r[0] *= self.accel_scale
            r[1] *= self.accel_scale
        else:  # no tilt information: the prediction, with a noise that gives it no weight
            roll, pitch = x[0], x[1]
            r[0] = r[1] = _NO_WEIGHT
        if g["gimbal_r"] >= 0.5:  # near pitch ±90° roll, yaw and their rates are ill-defined
            s = 1.0 / max(math.cos(x[1]) ** 2, cmin * cmin)
            r[0] *= s
            r[2] *= s
            r[3] *= s
            r[5] *= s
        yaw = self._heading(sample, x[0], x[1], Rm, dt, spin)
        z0 = x[0] + wrap_pi(roll - x[0])
        if yaw is not None:
            r[2] += (spin * g["mag_time_sigma"]) ** 2
            if self.heading_source == "mag":  # accelerating: the tilt, hence the levelled field, is less sure
                r[2] = max(r[2], g["yaw_acc_r"] * self.accel_dev)
            if dt < g["mag_dt"]:  # heading errors are correlated over mag_dt: more samples add no information
                r[2] *= g["mag_dt"] / dt
            if self.heading_source == "mag":  # a freshly learned hard-iron offset: less weight
                r[2] /= max(self.mag.weight, MAG_WEIGHT_MIN)
            H, R, zc = self._H6, self._R6, self._z6
            zc[:, 0] = (z0, pitch, x[2] + wrap_pi(yaw - x[2]), *rates)
            R[_DIAG6] = r
        else:  # no heading row
            H, R, zc = self._H5, self._R5, self._z5
            zc[:, 0] = (z0, pitch, *rates)
            R[_DIAG5] = (r[0], r[1], r[3], r[4], r[5])
        # column vector z: filterpy 2.0.0 skips its reshape of z when H is passed
        kf.update(zc, R=R, H=H)
        y = kf.y[:, 0].tolist()
        self.innovation = np.array(y if yaw is not None else (y[0], y[1], 0.0, y[2], y[3], y[4]))
        x = kf.x[:, 0].tolist()
        tau = g["bias_tau"]
        if tau > 0.0 and not self.shock.active and abs(self.accel_norm - G0) < g["bias_acc_tol"]:
            # what the update turned is, in the mean, the drift of the bias left in the gyro:
            # b ← b − δ/τ (δ the body-frame turn of the update) learns it over τ; only while
            # |f| ≈ g (a linear acceleration's tilt correction is no drift), and by default
            # only its tilt part (heading corrections also follow the field's changes in place)
            d = body_turn(q, euler_quat(x[0], x[1], x[2]))
            if g["bias_heading"] < 0.5:
                D = Rm[2]
                dd = d[0] * D[0] + d[1] * D[1] + d[2] * D[2]
                d = (d[0] - dd * D[0], d[1] - dd * D[1], d[2] - dd * D[2])
            self.bias = vec3(min(max(b[i] - d[i] / tau, -BIAS_MAX), BIAS_MAX) for i in range(3))
        # at rest the gyro reads its bias, heading axis included
        b = self.rest.update(sample.t, (gx, gy, gz), self.bias, (fx, fy, fz), self.gps.at(sample.t), dt, g)
        self.bias = vec3(min(max(v, -BIAS_MAX), BIAS_MAX) for v in b)
        if self.f_avg is not None and g["accel_tau"] > 0.0:
            # turn the average with the correction (earth frame, R⁺R⁻ᵀ), so it filters the
            # measurement without delaying the loop (as the DCM and VQF do)
            Rp = quat_rows(euler_quat(x[0], x[1], x[2]))
            fs = tuple(Rm[0][i] * self.f_avg[0] + Rm[1][i] * self.f_avg[1] + Rm[2][i] * self.f_avg[2] for i in range(3))
            self.f_avg = vec3(Rp[i][0] * fs[0] + Rp[i][1] * fs[1] + Rp[i][2] * fs[2] for i in range(3))
        kf.x[0, 0], kf.x[2, 0] = wrap_pi(x[0]), wrap_pi(x[2])
        return True

    @property
    def euler(self) -> tuple[float, float, float]:
        x = self.kf.x[:3, 0].tolist()
        return x[0], x[1], x[2]

    @property
    def quaternion(self) -> npt.NDArray[np.float64]:
        return np.array(euler_quat(*self.euler))

    def health(self) -> dict[str, HealthValue]:
        return {
            **self._common_health(),
            "valid": self.valid,
            "accel_norm": self.accel_norm,
            "heading_source": self.heading_source,
            **{f"innovation_{s}": float(v) for s, v in zip(_ANGLES + _RATES, self.innovation)},
            "accel_scale": self.accel_scale,
            "mag_disturbed": self.mag.disturbed,
            "mag_rejected": self.mag_rejected,
            "mag_offset": self.mag.offset,
            "shocks": self.shock.count,
            "gyro_bias": self.bias,
            **{f"sigma_{s}": float(math.sqrt(max(self.kf.P[i, i], 0.0))) for i, s in enumerate(_ANGLES + _RATES)},
        }
