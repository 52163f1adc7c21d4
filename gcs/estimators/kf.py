"""The linear Kalman attitude filter KF-A of seed 004 (Mendoza Robles 2022, §5.2.2 / §5.3.2),
fed raw IMU instead of PX4's own attitude."""

from __future__ import annotations

import math

import numpy as np
from filterpy.kalman import KalmanFilter

from gcs.estimators.base import COMMON_GAINS, GPS_GAINS, AttitudeEstimator, GpsAcceleration
from gcs.estimators.gains import Gain
from gcs.rotation import euler_to_quat, quat_to_matrix, wrap_pi
from gcs.sensors import G0, GpsSample, ImuSample

_ANGLES = ("roll", "pitch", "yaw")
_RATES = ("p", "q", "r")
#: Seed 004 Q (5.35; "reference" diagonal, per thesis step) and R (5.37), in state order.
SEED004_Q = (0.0259, 0.0257, 0.4051, 0.4047, 0.1952, 0.1940)
SEED004_R = (0.0202, 0.0842, 0.0066, 0.0006, 0.0025, 0.0034)


def accel_tilt(f, a_ned=(0.0, 0.0, 0.0), yaw: float = 0.0, roll: float = 0.0, pitch: float = 0.0):
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


def mag_heading(m, roll: float, pitch: float, declination: float) -> float | None:
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


def euler_rates(roll: float, pitch: float, gyro) -> tuple[float, float, float]:
    """Body rates → Z-Y-X Euler-angle rates, seed 004 eq. (4.9)."""
    p, q, r = (float(v) for v in gyro)
    sr, cr = math.sin(roll), math.cos(roll)
    cp = max(math.cos(pitch), 1e-6)
    tp = math.sin(pitch) / cp
    return p + (sr * q + cr * r) * tp, cr * q - sr * r, (sr * q + cr * r) / cp


class KalmanAttitudeFilter(AttitudeEstimator):
    """KF-A: linear Kalman filter on Euler angles and their rates (seed 004, §5.2.2).

    State x = [φ θ ψ φ̇ θ̇ ψ̇]ᵀ (5.19; p q r in the thesis code). Model (5.28)-(5.29):
    x⁻ = Φx + Bu, Φ = [[I, Δt·I], [0, I]], B = [[Δt²/2·I], [Δt·I]], H = I₆. Predict P⁻ = ΦPΦᵀ + Q, update with the filterpy
    `KalmanFilter` (Joseph form, equivalent to the thesis (I − KH)P for the optimal K).

    Measurements z = [φ_a θ_a ψ_m φ̇_g θ̇_g ψ̇_g]: tilt from the accelerometer (`accel_tilt`, with
    the GPS acceleration removed as in the DCM), heading from the tilt-compensated magnetometer
    (`mag_heading`, plus declination; without a magnetometer the GPS course above
    gps_speed_min, else no heading row), and the gyro mapped to Euler rates by (4.9).

    Deviations from the thesis, and why:
    * u is the Euler-angle acceleration from successive gyro samples, u = (ω̇ₖ − ω̇ₖ₋₁)/Δt with
      ω̇ the gyro mapped to Euler rates, and B = [[Δt²/2·I], [Δt·I]] (5.29 with I_x = I_y = I_z = 1):
      the thesis got the same quantity, τ/I, from commanded PWMs through the motor model, which
      a ground station fusing RAW_IMU does not have. It makes the angle prediction the
      trapezoid of two rate samples, not a one-step-late rectangle.
    * z comes from raw sensors, not PX4's attitude estimate (which the thesis filtered).
    * The gyro is mapped to Euler rates (4.9) instead of being used as φ̇θ̇ψ̇ (the hover
      linearisation), so the filter is right at large tilts and while yawing.
    * Δt is the real interval and Q is rebuilt for it: the thesis Q is per step of
      dt_ref = 4 ms, so Q(Δt) = k_q·diag(q)·Δt/dt_ref (white process noise); R is per sample.
    * Angle innovations (roll and yaw) are wrapped into (−π, π]: the measurement is shifted to
      the branch nearest the state before filterpy forms z − Hx; angles are wrapped after.
    * x₀ comes from the first sample (tilt, heading, rates) instead of 0; P₀ = unscaled Q (5.35).
    The filter inherits KF-A's limit: Euler angles are singular at pitch ±90°.
    Presets: `seed004` — Q diag, k_q = 0.03 and R as printed (Q 5.35, R 5.37); `telemetry` —
    the angle process noises q_roll, q_pitch, q_yaw 10⁴ times smaller, rates unchanged: the
    thesis Q let the angles follow PX4's smooth estimate, while raw accelerometer tilt is
    disturbed by every manoeuvre, so the angles must trust the integrated gyro. Default
    `telemetry`, the more accurate on the ArduCopter SITL hop (roll/pitch RMS vs SIMSTATE
    0.30°/0.22° against 1.75°/1.19° for `seed004`, tests/test_kf.py).
    """

    name = "kf"
    GAINS = (
        *(Gain(f"q_{s}", v, 0.0, 100.0, "rad²" if s in _ANGLES else "rad²/s²", f"process noise of {s} per dt_ref step")
          for s, v in zip(_ANGLES + _RATES, SEED004_Q)),
        *(Gain(f"r_{s}", v, 1e-8, 100.0, "rad²" if s in _ANGLES else "rad²/s²", f"measurement noise of {s}")
          for s, v in zip(_ANGLES + _RATES, SEED004_R)),
        Gain("k_q", 0.03, 0.0, 1000.0, "", "scale of the process noise Q (thesis k_q)"),
        Gain("dt_ref", 0.004, 1e-4, 1.0, "s", "the step the q_* values are given per (thesis: 4 ms)"),
    ) + GPS_GAINS + COMMON_GAINS
    PRESETS = {"seed004": {}, "telemetry": {"q_roll": 2.59e-6, "q_pitch": 2.57e-6, "q_yaw": 4.051e-5}}
    DEFAULT_PRESET = "telemetry"

    def __init__(self, preset: str | None = None, **gains: float) -> None:
        super().__init__(preset, **gains)
        self.kf = KalmanFilter(dim_x=6, dim_z=6, dim_u=3)
        self.rates_prev = (0.0, 0.0, 0.0)
        self.gps = GpsAcceleration()
        self.valid = False
        self.accel_norm = 0.0
        self.innovation = np.zeros(6)
        self.heading_source = "none"

    def _q(self, dt: float) -> np.ndarray:
        g = self.gains
        scale = g["k_q"] * dt / g["dt_ref"]
        return np.diag([g[f"q_{s}"] * scale for s in _ANGLES + _RATES])

    def _r(self) -> np.ndarray:
        return np.diag([self.gains[f"r_{s}"] for s in _ANGLES + _RATES])

    def update_gps(self, sample: GpsSample) -> None:
        self.gps.update(sample)

    def _heading(self, sample: ImuSample, roll: float, pitch: float) -> float | None:
        if sample.mag is not None:
            psi = mag_heading(sample.mag, roll, pitch, self.gains["declination"])
            if psi is not None:
                self.heading_source = "mag"
                return psi
        course = self.gps.course_at(sample.t, self.gains["gps_speed_min"])
        self.heading_source = "gps_course" if course is not None else "none"
        return course

    def update_imu(self, sample: ImuSample) -> bool:
        self.accel_norm = float(np.linalg.norm(sample.accel))
        dt = self._check_time(sample.t)
        if dt is None:
            if self.accel_norm < 1e-6:  # cannot level on a zero vector: wait for a usable sample
                self.t = None
                return self.valid
            roll, pitch = accel_tilt(sample.accel)
            yaw = self._heading(sample, roll, pitch) or 0.0
            self.rates_prev = euler_rates(roll, pitch, sample.gyro)
            self.kf.x = np.array([[roll], [pitch], [yaw], *([v] for v in self.rates_prev)])
            self.kf.P = np.diag([self.gains[f"q_{s}"] for s in _ANGLES + _RATES])
            self.valid = True
            return True
        if dt == 0.0:
            return self.valid
        kf = self.kf
        kf.F = np.eye(6)
        kf.F[0, 3] = kf.F[1, 4] = kf.F[2, 5] = dt
        kf.Q = self._q(dt)
        kf.B = np.vstack([np.eye(3) * (0.5 * dt * dt), np.eye(3) * dt])
        # Euler rates of this gyro sample at the attitude predicted by the current rates
        rates = euler_rates(kf.x[0, 0] + dt * kf.x[3, 0], kf.x[1, 0] + dt * kf.x[4, 0], sample.gyro)
        u = [(r - r0) / dt for r, r0 in zip(rates, self.rates_prev)]
        kf.predict(u=np.array(u).reshape(3, 1))  # column u: filterpy broadcasts a 1-D one
        x = kf.x[:, 0]
        x[0], x[2] = wrap_pi(x[0]), wrap_pi(x[2])
        a = self.gps.at(sample.t)
        k = self.gains["gps_gain"]
        roll, pitch = accel_tilt(sample.accel, (k * a[0], k * a[1], k * a[2]), x[2], x[0], x[1])
        if self.accel_norm < 1e-6:
            roll, pitch = x[0], x[1]
        yaw = self._heading(sample, x[0], x[1])
        z = [x[0] + wrap_pi(roll - x[0]), pitch, x[2] + wrap_pi((yaw if yaw is not None else x[2]) - x[2]),
             *rates]
        self.rates_prev = rates
        R = self._r()
        rows = [0, 1, 2, 3, 4, 5] if yaw is not None else [0, 1, 3, 4, 5]
        H = np.eye(6)[rows]
        # column vector z: filterpy skips its reshape when H is passed (packages-smoke.md §5)
        kf.update(np.array(z)[rows].reshape(-1, 1), R=R[np.ix_(rows, rows)], H=H)
        self.innovation = np.zeros(6)
        self.innovation[rows] = kf.y[:, 0]
        kf.x[0, 0], kf.x[2, 0] = wrap_pi(kf.x[0, 0]), wrap_pi(kf.x[2, 0])
        return True

    @property
    def euler(self) -> tuple[float, float, float]:
        x = self.kf.x[:, 0]
        return float(x[0]), float(x[1]), float(x[2])

    @property
    def quaternion(self) -> np.ndarray:
        return euler_to_quat(*self.euler)

    def health(self) -> dict[str, float | str]:
        return {
            **self._common_health(),
            "valid": self.valid,
            "accel_norm": self.accel_norm,
            "heading_source": self.heading_source,
            **{f"innovation_{s}": float(v) for s, v in zip(_ANGLES + _RATES, self.innovation)},
            **{f"sigma_{s}": float(math.sqrt(max(self.kf.P[i, i], 0.0))) for i, s in enumerate(_ANGLES + _RATES)},
        }
