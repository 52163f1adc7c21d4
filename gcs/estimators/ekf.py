"""`ekf`: a multiplicative (error-state) Kalman filter for attitude, velocity and gyro bias.

Sources: F. L. Markley, "Attitude Error Representations for Kalman Filtering", JGCD 26(2), 2003;
J. Solà, "Quaternion kinematics for the error-state Kalman filter", arXiv:1711.02508, 2017
(§5 for the inertial model, §7.2 for the global angular error).

State
    nominal:  q  unit quaternion sensor → NED,  v  NED velocity (m/s),  b  gyro bias (rad/s, sensor)
    error:    x = [δθ, δv, δb]  (9)   with  q_true = Exp(δθ) ⊗ q,  v_true = v + δv,  b_true = b + δb
δθ is a small rotation expressed in NED ("global" error, Solà §7.2): gyro noise is isotropic in
that frame, a velocity residual is a plain NED vector, and heading is simply δθ_D, which is what
lets the magnetometer correct heading only.

Why a velocity state. The accelerometer measures specific force a = Rᵀ(v̇ − g). Comparing a with
gravity sample by sample (a first-order filter) lets every linear acceleration tilt the estimate
in proportion to its size. Integrating it instead, v̇ = R·a + g, turns a tilt error δθ into a
velocity error that grows without bound (δv̇ = −[R·a]× δθ), while a real linear acceleration only
changes v by the bounded amount the body actually moved. So a velocity measurement — the GPS
velocity when there is one, else the pseudo-measurement "the velocity stays near zero" — corrects
the tilt with a second-order response that averages out back-and-forth motion. With GPS this is the
integral form of subtracting GPS-derived linear acceleration from the expected specific force
(AP_AHRS_DCM compares the same Δv over each GPS interval).

Prediction over dt with ω = gyro − b, R = R(q):
    q ← q ⊗ Exp(ω dt),   v ← v + (R a + g) dt
    F = I + [[0, 0, −R dt], [−[R a]× dt, 0, 0], [0, 0, 0]],   P ← F P Fᵀ + diag(σ_g², σ_a², σ_b²)·dt
σ_a (the accel noise density) grows as 1 + (d/acc_gate)² with d = | |a| − g |: while the sensor
is accelerating hard (impacts, tapping) the velocity, and so the tilt, trusts it less. The default
gate is wide on purpose: a norm gate is one-sided (it discounts the peaks of |a| more than the
troughs), which biases the average the velocity state relies on; on BROAD (6D, full rate) a 2 m/s²
gate doubled the inclination error of the fast combined-motion trial 30 (1.2° → 2.4°).

Measurements (y = residual, H = Jacobian in x, r = variance)
    velocity  y = v_meas − v,           H = [0, I, 0]  (GPS: N, E with gps_noise², against v at
                                                         the fix's own time, kept in a short
                                                         history; otherwise 0 with vel_noise²/dt
                                                         per sample)
    rest      y = gyro − b,             H = [0, 0, I]  (zero-rate update, after rest_time still)
              y = R a + g,              H = [[−g]×, 0, 0]  (gravity alone; not with GPS, where a
                                                         steady acceleration can look like rest)
    heading   y = wrap(decl − ψ(R m)),  H = e_3ᵀ       (ψ = azimuth of the field in NED)
The heading update keeps only its gain on δθ_D, so a disturbed field can never tilt the estimate:
not directly, and not later through the bias (a field error taken into the bias about the vertical
becomes a tilt drift once the body turns: 8° in the bent-field case of tests/test_ekf.py). The
bias is learned at rest and from gravity as the body turns. P is updated with the Joseph form,
valid for that non-optimal gain.
The heading noise grows with the departure of |m| and of the dip angle from the values learned at
initialisation; above mag_reject the update is skipped, and a field rejected for mag_relearn
seconds becomes the new reference (the vehicle moved, or started beside a magnet).

Units: gyro rad/s, accel m/s², magnetometer any consistent unit (only its direction and ratios to
the reference are used). Any right-handed sensor frame: at rest the specific force points up.
"""

from __future__ import annotations

import math
from collections import deque
from typing import ClassVar

import numpy as np

from gcs.estimators.base import COMMON_GAINS, AttitudeEstimator, initial_attitude
from gcs.estimators.gains import Gain
from gcs.rotation import matrix_to_quat, quat_from_rotvec, quat_multiply, quat_to_matrix, wrap_pi
from gcs.sensors import G0, GpsSample, ImuSample

_G_NED = np.array([0.0, 0.0, G0])
_TH, _V, _B = slice(0, 3), slice(3, 6), slice(6, 9)  # error-state blocks


def _skew(v: np.ndarray) -> np.ndarray:
    """[v]×, so that _skew(a) @ b == a × b."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


class EkfEstimator(AttitudeEstimator):
    """Error-state (multiplicative) Kalman filter of attitude, velocity and gyro bias.

    GPS velocity, or a bounded-velocity prior without GPS, removes linear acceleration; the
    magnetometer corrects heading only. Math and sources in the module docstring."""

    name: ClassVar[str] = "ekf"
    GAINS: ClassVar[tuple[Gain, ...]] = (
        Gain("gyro_noise", 0.01, 1e-5, 1.0, "rad/s/√Hz", "gyro noise density, including unmodelled errors in motion"),
        Gain("bias_walk", 1e-5, 0.0, 0.1, "rad/s/√s", "gyro bias random walk: how fast the bias may wander"),
        Gain("bias_init", 0.03, 0.0, 0.5, "rad/s", "1-σ uncertainty of the gyro bias at start"),
        Gain("acc_noise", 0.1, 1e-3, 100.0, "m/s²/√Hz", "accelerometer noise density, integrated into velocity"),
        Gain("acc_gate", 20.0, 0.01, 100.0, "m/s²", "| |a| − g | at which the accel noise has doubled"),
        Gain("vel_noise", 1.0, 1e-3, 100.0, "m/s·√s", "without GPS: how far the velocity may wander from zero"),
        Gain("gps_noise", 0.3, 0.01, 10.0, "m/s", "GPS horizontal velocity noise (1 σ)"),
        Gain("gps_delay", 0.0, 0.0, 1.0, "s", "age of the GPS velocity at its own timestamp"),
        Gain("gps_timeout", 1.0, 0.05, 10.0, "s", "GPS older than this no longer aids: back to the velocity prior"),
        Gain("mag_noise", 0.05, 1e-4, 10.0, "rad·√s", "magnetometer heading noise density"),
        Gain("mag_norm_gate", 0.1, 0.001, 10.0, "ratio", "relative |m| change doubling the mag noise"),
        Gain("mag_dip_gate", 0.1, 0.001, 3.0, "rad", "dip-angle departure from the reference doubling the mag noise"),
        Gain("mag_reject", 3.0, 1.0, 1e6, "×", "mag noise inflation above which the heading update is skipped"),
        Gain("mag_relearn", 20.0, 1.0, 3600.0, "s", "a field rejected this long becomes the new reference"),
        Gain("rest_gyro", 0.035, 0.0, 1.0, "rad/s", "bias-corrected rate below which the sensor may be at rest"),
        Gain("rest_acc", 0.5, 0.0, 10.0, "m/s²", "change of the accel vector allowed while at rest"),
        Gain("rest_time", 1.5, 0.1, 60.0, "s", "time both rest conditions must hold before zero-rate updates"),
        Gain("rest_noise", 1e-3, 1e-6, 1.0, "rad/s/√Hz", "gyro noise density during zero-rate updates at rest"),
        Gain("rest_acc_noise", 0.01, 1e-4, 10.0, "m/s²/√Hz", "accel noise density for the gravity update at rest"),
    ) + COMMON_GAINS
    PRESETS: ClassVar[dict[str, dict[str, float]]] = {
        "default": {},
        # 25-50 Hz RAW_IMU streams: picking samples makes the gyro integration coarser, and real
        # airframes vibrate (BROAD at 24 Hz: 6.0° vs 6.2° mean total with the default gains)
        "telemetry": {"gyro_noise": 0.02, "acc_noise": 0.5},
    }
    DEFAULT_PRESET: ClassVar[str] = "default"

    def __init__(self, preset: str | None = None, **gains: float) -> None:
        super().__init__(preset, **gains)
        self.q = np.array([1.0, 0.0, 0.0, 0.0])
        self.v = np.zeros(3)
        self.b = np.zeros(3)
        self.P = np.zeros((9, 9))
        self.initialised = False
        # velocity history for delayed GPS: (t, v − corrections so far); see _velocity_at
        self._v_hist: deque[tuple[float, np.ndarray]] = deque()
        self._v_offset = np.zeros(3)
        self._gps_t = -math.inf
        self._rest_since = -math.inf
        self._rest_acc: np.ndarray | None = None
        self.mag_ref_norm = 0.0
        self.mag_ref_dip = 0.0
        self._mag_rejected_since: float | None = None
        self.stats: dict[str, float] = {
            "accel_norm": 0.0, "acc_inflation": 1.0, "vel_innov": 0.0, "gps_nis": 0.0, "gps_aided": 0,
            "mag_nis": 0.0, "mag_innov_deg": 0.0, "mag_disturbance": 0.0, "mag_rejected": 0, "mag_relearned": 0,
            "at_rest": 0, "dropped": 0,
        }  # fmt: skip

    # -- public API ---------------------------------------------------------------------------
    @property
    def quaternion(self) -> np.ndarray:
        return self.q.copy()

    def health(self) -> dict[str, float | str]:
        h: dict[str, float | str] = {**self._common_health(), **self.stats}
        h.update(bias_x=float(self.b[0]), bias_y=float(self.b[1]), bias_z=float(self.b[2]))
        h["tilt_sigma_deg"] = math.degrees(math.sqrt(max(self.P[0, 0] + self.P[1, 1], 0.0)))
        h["heading_sigma_deg"] = math.degrees(math.sqrt(max(self.P[2, 2], 0.0)))
        return h

    def update_imu(self, sample: ImuSample) -> bool:
        gyro = np.asarray(sample.gyro, float)
        accel = np.asarray(sample.accel, float)
        mag = None if sample.mag is None else np.asarray(sample.mag, float)
        if mag is not None and not (np.all(np.isfinite(mag)) and np.any(mag)):
            mag = None
        if not (np.all(np.isfinite(gyro)) and np.all(np.isfinite(accel))):
            self.stats["dropped"] += 1
            return self.initialised
        dt = self._check_time(sample.t)
        if dt is None or not self.initialised:
            return self._initialise(sample.t, accel, mag)
        if dt == 0.0:
            return True
        self._predict(gyro, accel, dt, sample.t)
        aided = sample.t - self._gps_t <= self.gains["gps_timeout"]
        self.stats["gps_aided"] = int(aided)
        if self._at_rest(sample.t, gyro, accel):
            self._update_zero_rate(gyro, dt)
            if not aided:  # with GPS, a steady acceleration is not taken for rest
                self._update_gravity(accel, dt)
        self._update_velocity_prior(dt, (2,) if aided else (0, 1, 2))
        if mag is not None:
            self._update_heading(mag, dt)
        return True

    def update_gps(self, sample: GpsSample) -> None:
        """Fuse the horizontal GPS velocity at its own time (GPS_RAW_INT has no vertical speed)."""
        if sample.fix_type < 3 or sample.vel_ned is None or not self.initialised or sample.t <= self._gps_t:
            return
        vel = np.asarray(sample.vel_ned, float)
        if self.t is None or self.t - self._gps_t > self.gains["gps_timeout"]:
            # (re)acquired: the velocity state was only a bounded prior; start it from the fix
            self._shift_velocity(np.array([vel[0] - self.v[0], vel[1] - self.v[1], 0.0]))
            self.P[3:5, :] = 0.0
            self.P[:, 3:5] = 0.0
            self.P[3, 3] = self.P[4, 4] = self.gains["gps_noise"] ** 2
        else:
            y = vel[:2] - self._velocity_at(sample.t - self.gains["gps_delay"])[:2]
            r = self.gains["gps_noise"] ** 2
            PHt = self.P[:, 3:5]
            S_inv = np.linalg.inv(PHt[3:5] + r * np.eye(2))
            self._apply(PHt @ S_inv, PHt, y)
            self.stats["gps_nis"] = float(y @ S_inv @ y)
            self.stats["vel_innov"] = math.hypot(y[0], y[1])
        self._gps_t = sample.t

    # -- filter steps -------------------------------------------------------------------------
    def _initialise(self, t: float, accel: np.ndarray, mag: np.ndarray | None) -> bool:
        """Attitude from this sample (base policy); velocity zero; the bias estimate is kept."""
        if accel @ accel < 1e-6:
            return False
        R = initial_attitude(accel, mag, self.gains["declination"])
        self.q = matrix_to_quat(R)
        self.v = np.zeros(3)
        self._v_hist.clear()
        self._v_offset = np.zeros(3)
        self._gps_t = -math.inf
        self.stats["gps_aided"] = 0
        tilt_var = math.radians(5.0) ** 2
        heading_var = math.radians(20.0 if mag is not None else 180.0) ** 2
        vel_var = self.gains["vel_noise"] ** 2
        bias_var = self.gains["bias_init"] ** 2
        self.P = np.diag([tilt_var, tilt_var, heading_var] + [vel_var] * 3 + [bias_var] * 3)
        self.mag_ref_norm = 0.0
        if mag is not None:
            self._learn_mag_reference(R @ mag)
        self.initialised = True
        return True

    def _predict(self, gyro: np.ndarray, accel: np.ndarray, dt: float, t: float) -> None:
        """Strapdown q and v over dt (the sample's accel at the step's end attitude); propagate P."""
        self.q = quat_multiply(self.q, quat_from_rotvec((gyro - self.b) * dt))
        self.q /= math.sqrt(self.q @ self.q)
        R = quat_to_matrix(self.q)
        f_n = R @ accel
        self.v = self.v + (f_n + _G_NED) * dt
        self._v_hist.append((t, self.v - self._v_offset))
        while self._v_hist and self._v_hist[0][0] < t - 2.0 * self.gains["gps_timeout"]:
            self._v_hist.popleft()

        a_norm = math.sqrt(accel @ accel)
        inflation = 1.0 + ((a_norm - G0) / self.gains["acc_gate"]) ** 2
        self.stats["accel_norm"] = a_norm
        self.stats["acc_inflation"] = inflation
        F = np.eye(9)
        F[_TH, _B] = -R * dt
        F[_V, _TH] = -_skew(f_n) * dt
        sa = self.gains["acc_noise"] * inflation
        q_diag = np.repeat([self.gains["gyro_noise"] ** 2, sa * sa, self.gains["bias_walk"] ** 2], 3) * dt
        self.P = F @ self.P @ F.T + np.diag(q_diag)

    def _apply(self, K: np.ndarray, PHt: np.ndarray, y: np.ndarray) -> None:
        """Optimal-gain covariance update P − K (P Hᵀ)ᵀ and injection of K y into the nominal state."""
        P = self.P - K @ PHt.T
        self.P = 0.5 * (P + P.T)
        self._inject(K @ y)

    def _inject(self, dx: np.ndarray) -> None:
        """Move the error estimate into the nominal state (the error resets to zero)."""
        self.q = quat_multiply(quat_from_rotvec(dx[_TH]), self.q)
        self.q /= math.sqrt(self.q @ self.q)
        self._shift_velocity(dx[_V])
        self.b = self.b + dx[_B]

    def _shift_velocity(self, dv: np.ndarray) -> None:
        self.v = self.v + dv
        self._v_offset = self._v_offset + dv

    def _velocity_at(self, t: float) -> np.ndarray:
        """Velocity at an earlier time t, with every correction made since applied to it too."""
        v_then = self.v - self._v_offset
        for t_i, v_i in reversed(self._v_hist):
            v_then = v_i
            if t_i <= t:
                break
        return v_then + self._v_offset

    def _update_velocity_prior(self, dt: float, axes: tuple[int, ...]) -> None:
        """Pseudo-measurement v = 0 on the given NED axes: motion without GPS is bounded."""
        idx = [3 + i for i in axes]
        r = self.gains["vel_noise"] ** 2 / dt
        PHt = self.P[:, idx]
        S_inv = np.linalg.inv(PHt[idx] + r * np.eye(len(idx)))
        y = -self.v[list(axes)]
        if len(axes) == 3:
            self.stats["vel_innov"] = math.sqrt(y @ y)
        self._apply(PHt @ S_inv, PHt, y)

    def _at_rest(self, t: float, gyro: np.ndarray, accel: np.ndarray) -> bool:
        """Still for rest_time: small bias-corrected rate and an accel vector that has not moved."""
        w = gyro - self.b
        still = w @ w < self.gains["rest_gyro"] ** 2
        if still and self._rest_acc is not None:
            da = accel - self._rest_acc
            still = da @ da < self.gains["rest_acc"] ** 2
        if not still or self._rest_acc is None:
            self._rest_since, self._rest_acc = t, accel
            self.stats["at_rest"] = 0
            return False
        self.stats["at_rest"] = int(t - self._rest_since >= self.gains["rest_time"])
        return bool(self.stats["at_rest"])

    def _update_gravity(self, accel: np.ndarray, dt: float) -> None:
        """At rest the specific force is gravity alone: y = R a + g, H = [[−g]×, 0, 0]."""
        r = self.gains["rest_acc_noise"] ** 2 / dt
        U = _skew(-_G_NED)
        PHt = self.P[:, _TH] @ U.T
        S_inv = np.linalg.inv(U @ PHt[_TH] + r * np.eye(3))
        self._apply(PHt @ S_inv, PHt, quat_to_matrix(self.q) @ accel + _G_NED)

    def _update_zero_rate(self, gyro: np.ndarray, dt: float) -> None:
        """At rest the true rate is zero, so the gyro reads its bias: y = gyro − b, H = [0, 0, I]."""
        r = self.gains["rest_noise"] ** 2 / dt
        PHt = self.P[:, _B]
        S_inv = np.linalg.inv(PHt[_B] + r * np.eye(3))
        self._apply(PHt @ S_inv, PHt, gyro - self.b)

    def _learn_mag_reference(self, m_n: np.ndarray) -> None:
        """|m| and dip angle of the undisturbed field, from a field vector in NED."""
        self.mag_ref_norm = math.sqrt(m_n @ m_n)
        self.mag_ref_dip = math.atan2(m_n[2], math.hypot(m_n[0], m_n[1]))
        self._mag_rejected_since = None

    def _update_heading(self, mag: np.ndarray, dt: float) -> None:
        m_n = quat_to_matrix(self.q) @ mag
        m_h = math.hypot(m_n[0], m_n[1])
        m_norm = math.sqrt(mag @ mag)
        if m_h < 1e-3 * m_norm:
            self.stats["mag_rejected"] += 1
            return
        dip = math.atan2(m_n[2], m_h)
        if self.mag_ref_norm == 0.0:  # no field at initialisation
            self._learn_mag_reference(m_n)
        norm_dev = (m_norm / self.mag_ref_norm - 1.0) / self.gains["mag_norm_gate"]
        dip_dev = (dip - self.mag_ref_dip) / self.gains["mag_dip_gate"]
        inflation = 1.0 + norm_dev * norm_dev + dip_dev * dip_dev
        self.stats["mag_disturbance"] = inflation - 1.0
        if inflation > self.gains["mag_reject"]:
            self.stats["mag_rejected"] += 1
            if self._mag_rejected_since is None:
                self._mag_rejected_since = self.t
            elif self.t - self._mag_rejected_since >= self.gains["mag_relearn"]:
                self._learn_mag_reference(m_n)
                self.stats["mag_relearned"] += 1
            return
        self._mag_rejected_since = None
        sigma = self.gains["mag_noise"] * inflation * m_norm / m_h
        r = sigma * sigma / dt
        y = wrap_pi(self.gains["declination"] - math.atan2(m_n[1], m_n[0]))
        p = self.P[:, 2].copy()
        s = p[2] + r
        K = np.zeros(9)  # heading only (see the module docstring)
        K[2] = p[2] / s
        self.P = self.P - np.outer(K, p) - np.outer(p, K) + s * np.outer(K, K)
        self.stats["mag_nis"] = y * y / s
        self.stats["mag_innov_deg"] = math.degrees(y)
        self._inject(K * y)
