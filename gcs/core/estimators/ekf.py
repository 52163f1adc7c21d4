"""`ekf`: a multiplicative (error-state) Kalman filter for attitude, velocity and gyro bias.

Nominal q (sensor → NED), v (NED), b (gyro bias); error x = [δθ, δv, δb] with q_true = Exp(δθ) ⊗ q and δθ
in NED (Markley 2003; Solà 2017, §5 and §7.2). Prediction: q ← q ⊗ Exp((gyro − b) dt), v ← v + (R a + g) dt,
P ← F P Fᵀ + Q dt. The accelerometer is integrated into a velocity, corrected by GPS velocity (or by a
"velocity stays near zero" prior), which cancels linear acceleration; at rest, zero-rate and gravity updates
learn the bias; the magnetometer corrects heading only (gain on δθ_D, Joseph form), its noise growing with
the field's departure from the reference. Plain-float state and closed-form small inverses keep what-if
re-runs fast; each step equals a plain transcription of the equations to rounding.
Equations, measurements, gains and why: docs/estimators/ekf.md
"""

from __future__ import annotations

import math
from collections import deque
from typing import ClassVar

import numpy as np
import numpy.typing as npt

from gcs.core.estimators.base import (
    COMMON_GAINS,
    PICK_GAINS,
    SHOCK_GAINS,
    AttitudeEstimator,
    HealthValue,
    Shock,
    initial_attitude,
)
from gcs.core.estimators.magnetic import MAG_GAINS, MAG_TIME_SIGMA, MAG_WEIGHT_MIN, MagneticHeading
from gcs.core.estimators.rest import REST_TEST_GAINS, RestTest
from gcs.core.gains import Gain
from gcs.core.rotation import Quat, Vec3, matrix_to_quat, quat_exp, quat_mul, quat_rows, quat_unit, rows_times
from gcs.core.samples import G0, GpsSample, ImuSample

_TH, _V, _B = slice(0, 3), slice(3, 6), slice(6, 9)  # error-state blocks
#: Tilt 1-σ (rad) above which the field's dip says nothing yet: its reference is not kept.
MAG_SETTLE_TILT = math.radians(3.0)
#: The field's timing errors against the gyro's are correlated over this (s; kf's `mag_dt`): its
#: (|ω|·mag_time_sigma)² is a variance per this much time, not per sample.
MAG_TIME_DT = 0.02
_U = np.array([[0.0, G0, 0.0], [-G0, 0.0, 0.0]])  # the non-zero rows of [−g]×, g = (0, 0, G0)


def _inv_sym(S: list[list[float]]) -> list[list[float]]:
    """Inverse of a symmetric 1×1, 2×2 or 3×3 matrix (adjugate / determinant)."""
    if len(S) == 1:
        return [[1.0 / S[0][0]]]
    if len(S) == 2:
        (a, b), (_, d) = S
        det = a * d - b * b
        return [[d / det, -b / det], [-b / det, a / det]]
    (a, b, c), (_, d, e), (_, _, f) = S
    A, B, C = d * f - e * e, c * e - b * f, b * e - c * d
    D, E, F = a * f - c * c, b * c - a * e, a * d - b * b
    det = a * A + b * B + c * C
    return [[A / det, B / det, C / det], [B / det, D / det, E / det], [C / det, E / det, F / det]]


def _plus_r(block: npt.NDArray[np.float64], r: float) -> list[list[float]]:
    """block + r I, as lists (S = H P Hᵀ + r I for the closed-form inverse)."""
    S: list[list[float]] = block.tolist()
    for i, row in enumerate(S):
        row[i] += r
    return S


class EkfEstimator(AttitudeEstimator):
    """Error-state (multiplicative) Kalman filter of attitude, velocity and gyro bias.

    GPS velocity, or a bounded-velocity prior without GPS, removes linear acceleration; the
    magnetometer corrects heading only. Equations and sources: docs/estimators/ekf.md"""

    name: ClassVar[str] = "ekf"
    GAINS: ClassVar[tuple[Gain, ...]] = (
        (
            Gain(
                "gyro_noise", 0.01, 1e-5, 1.0, "rad/s/√Hz", "gyro noise density, including unmodelled errors in motion"
            ),
            Gain(
                "heading_noise", 0.01, 1e-5, 1.0, "rad/s/√Hz", "heading error growth in motion (gyro_noise, vertical)"
            ),
            Gain("bias_walk", 1e-5, 0.0, 0.1, "rad/s/√s", "gyro bias random walk: how fast the bias may wander"),
            Gain("bias_init", 0.03, 0.0, 0.5, "rad/s", "1-σ uncertainty of the gyro bias at start"),
            Gain("acc_noise", 0.1, 1e-3, 100.0, "m/s²/√Hz", "accelerometer noise density, integrated into velocity"),
            Gain("acc_gate", 20.0, 0.01, 100.0, "m/s²", "| |a| − g | at which the accel noise has doubled"),
            Gain("vel_noise", 1.0, 1e-3, 100.0, "m/s·√s", "without GPS: how far the velocity may wander from zero"),
            Gain("gps_noise", 0.3, 0.01, 10.0, "m/s", "GPS horizontal velocity noise (1 σ)"),
            Gain("gps_delay", 0.0, 0.0, 1.0, "s", "age of the GPS velocity at its own timestamp"),
            Gain("gps_timeout", 1.0, 0.05, 10.0, "s", "GPS older than this no longer aids: back to the velocity prior"),
            Gain("mag_noise", 0.05, 1e-4, 10.0, "rad·√s", "magnetometer heading noise density"),
            Gain("mag_time_sigma", MAG_TIME_SIGMA, 0.0, 1.0, "s", "field sample timing uncertainty: R + (|ω|·σ_t)²"),
            *REST_TEST_GAINS,
            Gain("rest_noise", 1e-3, 1e-6, 1.0, "rad/s/√Hz", "gyro noise density during zero-rate updates at rest"),
            Gain("rest_acc_noise", 0.01, 1e-4, 10.0, "m/s²/√Hz", "accel noise density for the gravity update at rest"),
        )
        + PICK_GAINS
        + MAG_GAINS
        + SHOCK_GAINS
        + COMMON_GAINS
    )
    PRESETS: ClassVar[dict[str, dict[str, float]]] = {
        "default": {},
        # 25-50 Hz RAW_IMU streams: picking samples makes the gyro integration coarser, and real
        # airframes vibrate (measured on BROAD: docs/benchmarks.md)
        "telemetry": {"gyro_noise": 0.02, "heading_noise": 0.02, "acc_noise": 0.5},
    }
    DEFAULT_PRESET: ClassVar[str] = "default"

    def __init__(self, preset: str | None = None, **gains: float) -> None:
        super().__init__(preset, **gains)
        self.q: Quat = (1.0, 0.0, 0.0, 0.0)
        self.v: Vec3 = (0.0, 0.0, 0.0)
        self.b: Vec3 = (0.0, 0.0, 0.0)
        self._gyro_prev: list[float] | None = None  # the last sample's gyro, for picked samples
        self.P = np.zeros((9, 9))
        self._F = np.eye(9)  # only F[_TH, _B] and F[_V, _TH] change (see _predict)
        self._FP = np.empty((9, 9))
        self.initialised = False
        # velocity history for delayed GPS: (t, v − corrections so far); see _velocity_at
        self._v_hist: deque[tuple[float, Vec3]] = deque()
        self._v_offset: Vec3 = (0.0, 0.0, 0.0)
        self._gps_t = -math.inf
        self.rest = RestTest()
        self.mag = MagneticHeading()
        self.shock = Shock()
        self.stats: dict[str, float] = {
            "accel_norm": 0.0, "acc_inflation": 1.0, "vel_innov": 0.0, "gps_nis": 0.0, "gps_aided": 0,
            "mag_nis": 0.0, "mag_innov_deg": 0.0, "mag_rejected": 0, "at_rest": 0, "dropped": 0,
        }  # fmt: skip

    # -- public API ---------------------------------------------------------------------------
    @property
    def quaternion(self) -> npt.NDArray[np.float64]:
        return np.array(self.q)

    def health(self) -> dict[str, HealthValue]:
        h: dict[str, HealthValue] = {**self._common_health(), **self.stats}
        h.update(bias_x=self.b[0], bias_y=self.b[1], bias_z=self.b[2])
        h.update(mag_disturbed=self.mag.disturbed, mag_offset=self.mag.offset, mag_relearned=self.mag.relearned)
        h.update(mag_offsets_learned=self.mag.offsets_learned, shocks=self.shock.count)
        h["tilt_sigma_deg"] = math.degrees(math.sqrt(max(self.P[0, 0] + self.P[1, 1], 0.0)))
        h["heading_sigma_deg"] = math.degrees(math.sqrt(max(self.P[2, 2], 0.0)))
        return h

    def update_imu(self, sample: ImuSample) -> bool:
        gyro = np.asarray(sample.gyro, float).tolist()
        accel = np.asarray(sample.accel, float).tolist()
        mag = None if sample.mag is None else np.asarray(sample.mag, float).tolist()
        if mag is not None and not (all(map(math.isfinite, mag)) and any(mag)):
            mag = None
        if not all(map(math.isfinite, gyro + accel)):
            self.stats["dropped"] += 1
            return self.initialised
        dt = self._check_time(sample.t)
        if dt is None or not self.initialised:
            return self._initialise(sample.t, gyro, accel, mag)
        if dt == 0.0:
            return True
        g = self.gains.values
        spin = math.sqrt(gyro[0] * gyro[0] + gyro[1] * gyro[1] + gyro[2] * gyro[2])
        a_norm = math.sqrt(accel[0] * accel[0] + accel[1] * accel[1] + accel[2] * accel[2])
        shock = self.shock.update(sample.t, a_norm, spin, g)
        self._predict(gyro, accel, dt, sample.t, shock)
        if self.shock.saturated:
            self._saturated(spin, dt)
        aided = sample.t - self._gps_t <= g["gps_timeout"]
        self.stats["gps_aided"] = int(aided)
        if shock:
            self.rest.interrupt()
        elif self._at_rest(sample.t, gyro, accel):
            self._update_zero_rate(gyro, dt)
            if not aided:  # with GPS, a steady acceleration is not taken for rest
                self._update_gravity(accel, dt)
        self._update_velocity_prior(dt, 1 if aided else 3)
        if mag is not None:
            self._update_heading(mag, gyro, dt)
        return True

    def update_gps(self, sample: GpsSample) -> None:
        """Fuse the horizontal GPS velocity at its own time (GPS_RAW_INT has no vertical speed)."""
        if sample.fix_type < 3 or sample.vel_ned is None or not self.initialised or sample.t <= self._gps_t:
            return
        vel = np.asarray(sample.vel_ned, float).tolist()
        if self.t is None or self.t - self._gps_t > self.gains["gps_timeout"]:
            # (re)acquired: the velocity state was only a bounded prior; start it from the fix
            self._shift_velocity((vel[0] - self.v[0], vel[1] - self.v[1], 0.0))
            self.P[3:5, :] = 0.0
            self.P[:, 3:5] = 0.0
            self.P[3, 3] = self.P[4, 4] = self.gains["gps_noise"] ** 2
        else:
            v_then = self._velocity_at(sample.t - self.gains["gps_delay"])
            y = [vel[0] - v_then[0], vel[1] - v_then[1]]
            r = self.gains["gps_noise"] ** 2
            (a, b), (_, d) = self._update(self.P[:, 3:5], _plus_r(self.P[3:5, 3:5], r), y)
            self.stats["gps_nis"] = a * y[0] * y[0] + 2.0 * b * y[0] * y[1] + d * y[1] * y[1]
            self.stats["vel_innov"] = math.hypot(y[0], y[1])
        self._gps_t = sample.t

    # -- filter steps -------------------------------------------------------------------------
    def _initialise(self, t: float, gyro: list[float], accel: list[float], mag: list[float] | None) -> bool:
        """Attitude from this sample (base policy); velocity zero; the bias estimate is kept."""
        if accel[0] * accel[0] + accel[1] * accel[1] + accel[2] * accel[2] < 1e-6:
            return False
        force = self._start_force(t, gyro, accel, mag is not None)
        if force is None:  # no heading yet: start from the next field
            self.initialised = False
            return False
        R = initial_attitude(force, None if mag is None else np.array(mag), self.gains["declination"])
        self.q = tuple(matrix_to_quat(R).tolist())
        self.v = (0.0, 0.0, 0.0)
        self._gyro_prev = None
        self._v_hist.clear()
        self._v_offset = (0.0, 0.0, 0.0)
        self._gps_t = -math.inf
        self.stats["gps_aided"] = 0
        tilt_var = math.radians(5.0) ** 2
        heading_var = math.radians(20.0 if mag is not None else 180.0) ** 2
        vel_var = self.gains["vel_noise"] ** 2
        bias_var = self.gains["bias_init"] ** 2
        self.P = np.diag([tilt_var, tilt_var, heading_var] + [vel_var] * 3 + [bias_var] * 3)
        self.mag = MagneticHeading()
        self.shock = Shock()
        self.initialised = True
        return True

    def _predict(self, gyro: list[float], accel: list[float], dt: float, t: float, shock: bool) -> None:
        """Strapdown q and v over dt (the sample's accel at the step's end attitude); propagate P.
        Through a shock the accelerometer measures the impact: the specific force is taken as
        gravity alone (v held) and its noise inflated as for the impact.

        The turn over dt: a log's every sample is the mean rate over the interval before it
        (w dt); a slower stream (dt > pick_dt: RAW_IMU at 25-50 Hz) picks samples, each the rate
        at its instant, so the rate is taken as linear between the last two, whose exact turn
        to second order is the trapezoid plus the coning term (w0 × w1) dt²/12 (Savage 1998)."""
        g = self.gains.values
        bx, by, bz = self.b
        w1 = (gyro[0] - bx, gyro[1] - by, gyro[2] - bz)
        prev, self._gyro_prev = self._gyro_prev, gyro
        if prev is None or dt <= g["pick_dt"]:
            turn = (w1[0] * dt, w1[1] * dt, w1[2] * dt)
        else:
            w0 = (prev[0] - bx, prev[1] - by, prev[2] - bz)
            h, c = 0.5 * dt, dt * dt / 12.0
            turn = (
                (w0[0] + w1[0]) * h + (w0[1] * w1[2] - w0[2] * w1[1]) * c,
                (w0[1] + w1[1]) * h + (w0[2] * w1[0] - w0[0] * w1[2]) * c,
                (w0[2] + w1[2]) * h + (w0[0] * w1[1] - w0[1] * w1[0]) * c,
            )
        self.q = q = quat_unit(quat_mul(self.q, quat_exp(*turn)))
        R = quat_rows(q)
        fx, fy, fz = (0.0, 0.0, -G0) if shock else rows_times(R, accel)
        vx, vy, vz = self.v
        self.v = v = (vx + fx * dt, vy + fy * dt, vz + (fz + G0) * dt)
        ox, oy, oz = self._v_offset
        self._v_hist.append((t, (v[0] - ox, v[1] - oy, v[2] - oz)))
        while self._v_hist and self._v_hist[0][0] < t - 2.0 * g["gps_timeout"]:
            self._v_hist.popleft()

        a_norm = math.sqrt(accel[0] * accel[0] + accel[1] * accel[1] + accel[2] * accel[2])
        inflation = 1.0 + ((a_norm - G0) / g["acc_gate"]) ** 2
        self.stats["accel_norm"] = a_norm
        self.stats["acc_inflation"] = inflation
        F = self._F
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R
        F[_TH, _B] = (
            (-r00 * dt, -r01 * dt, -r02 * dt),
            (-r10 * dt, -r11 * dt, -r12 * dt),
            (-r20 * dt, -r21 * dt, -r22 * dt),
        )  # −R dt
        F[_V, _TH] = ((0.0, fz * dt, -fy * dt), (-fz * dt, 0.0, fx * dt), (fy * dt, -fx * dt, 0.0))  # −[R a]× dt
        np.matmul(F, self.P, out=self._FP)
        self.P = self._FP @ F.T
        sa = g["acc_noise"] * inflation
        qg, qh = g["gyro_noise"] ** 2 * dt, g["heading_noise"] ** 2 * dt
        qa, qb = sa * sa * dt, g["bias_walk"] ** 2 * dt
        self.P.reshape(-1)[::10] += (qg, qg, qh, qa, qa, qa, qb, qb, qb)  # the diagonal of P (δθ in NED)

    def _update(self, PHt: npt.NDArray[np.float64], S: list[list[float]], y: list[float]) -> list[list[float]]:
        """Optimal gain K = P Hᵀ S⁻¹, P ← P − K (P Hᵀ)ᵀ (symmetrised), and injection of K y into
        the nominal state. Returns S⁻¹."""
        S_inv = _inv_sym(S)
        K = PHt @ np.array(S_inv)
        P = self.P - K @ PHt.T
        self.P = 0.5 * (P + P.T)
        self._inject(np.dot(K, y).tolist())
        return S_inv

    def _inject(self, dx: list[float]) -> None:
        """Move the error estimate into the nominal state (the error resets to zero)."""
        self.q = quat_unit(quat_mul(quat_exp(dx[0], dx[1], dx[2]), self.q))
        self._shift_velocity((dx[3], dx[4], dx[5]))
        bx, by, bz = self.b
        self.b = (bx + dx[6], by + dx[7], bz + dx[8])

    def _shift_velocity(self, dv: Vec3) -> None:
        vx, vy, vz = self.v
        ox, oy, oz = self._v_offset
        self.v = (vx + dv[0], vy + dv[1], vz + dv[2])
        self._v_offset = (ox + dv[0], oy + dv[1], oz + dv[2])

    def _velocity_at(self, t: float) -> Vec3:
        """Velocity at an earlier time t, with every correction made since applied to it too."""
        ox, oy, oz = self._v_offset
        v_then = (self.v[0] - ox, self.v[1] - oy, self.v[2] - oz)
        for t_i, v_i in reversed(self._v_hist):
            v_then = v_i
            if t_i <= t:
                break
        return v_then[0] + ox, v_then[1] + oy, v_then[2] + oz

    def _update_velocity_prior(self, dt: float, axes: int) -> None:
        """Pseudo-measurement v = 0 on the last `axes` NED axes (3: all, 1: down only): motion
        without GPS is bounded."""
        idx = slice(6 - axes, 6)
        r = self.gains.values["vel_noise"] ** 2 / dt
        y = [-v for v in self.v[3 - axes :]]
        if axes == 3:
            self.stats["vel_innov"] = math.sqrt(y[0] * y[0] + y[1] * y[1] + y[2] * y[2])
        self._update(self.P[:, idx], _plus_r(self.P[idx, idx], r), y)

    def _at_rest(self, t: float, gyro: list[float], accel: list[float]) -> bool:
        """Still for rest_time (rest.RestTest: small bias-corrected rate, an accel vector that has
        not moved)."""
        w = (gyro[0] - self.b[0], gyro[1] - self.b[1], gyro[2] - self.b[2])
        self.stats["at_rest"] = int(self.rest.update(t, w, (accel[0], accel[1], accel[2]), self.gains.values))
        return bool(self.stats["at_rest"])

    def _update_gravity(self, accel: list[float], dt: float) -> None:
        """At rest the specific force is gravity alone: y = R a + g, H = [[−g]×, 0, 0] (its third
        row is zero: y_D has no gain and is left out)."""
        r = self.gains["rest_acc_noise"] ** 2 / dt
        PHt = self.P[:, _TH] @ _U.T
        fx, fy, _ = rows_times(quat_rows(self.q), accel)
        self._update(PHt, _plus_r(_U @ PHt[_TH], r), [fx, fy])

    def _update_zero_rate(self, gyro: list[float], dt: float) -> None:
        """At rest the true rate is zero, so the gyro reads its bias: y = gyro − b, H = [0, 0, I]."""
        r = self.gains["rest_noise"] ** 2 / dt
        y = [gyro[0] - self.b[0], gyro[1] - self.b[1], gyro[2] - self.b[2]]
        self._update(self.P[:, _B], _plus_r(self.P[_B, _B], r), y)

    def _saturated(self, spin: float, dt: float) -> None:
        """A saturated gyro turned by an unknown amount above its reading: the whole step's turn
        becomes attitude uncertainty, and the heading is no longer trusted over the field."""
        q = (spin * dt) ** 2
        self.P.reshape(-1)[0:30:10] += q
        self.mag.distrust_heading()

    def _update_heading(self, mag: list[float], gyro: list[float], dt: float) -> None:
        """Heading from the field the shared test passes (magnetic.py: m − b, hard iron removed)."""
        g = self.gains.values
        R = quat_rows(self.q)
        bx, by, bz = self.b
        settling = self.P[0, 0] + self.P[1, 1] > MAG_SETTLE_TILT**2
        mc = self.mag.field((mag[0], mag[1], mag[2]), R, dt, math.dist(gyro, (bx, by, bz)), g, settling)
        if mc is None:
            self.stats["mag_rejected"] += 1
            return
        m_n = rows_times(R, mc)
        m_h = math.hypot(m_n[0], m_n[1])
        m_norm = math.sqrt(mc[0] * mc[0] + mc[1] * mc[1] + mc[2] * mc[2])
        if m_h < 1e-3 * m_norm:
            self.stats["mag_rejected"] += 1
            return
        sigma = g["mag_noise"] * m_norm / m_h
        # a field sample is rarely simultaneous with the gyro's: worth |ω|·σ_t of heading in a turn
        turn = math.dist(gyro, (bx, by, bz)) * g["mag_time_sigma"]
        r = (sigma * sigma / dt + turn * turn * max(1.0, MAG_TIME_DT / dt)) / max(self.mag.weight, MAG_WEIGHT_MIN)
        y = self.mag.yaw_error
        # K = k e_3 (heading only, see the module docstring); Joseph form P − K pᵀ − p Kᵀ + s K Kᵀ
        P = self.P
        p = P[:, 2].copy()
        s = float(p[2]) + r
        k = float(p[2]) / s
        kp = k * p
        P[2] -= kp
        P[:, 2] -= kp
        P[2, 2] += s * (k * k)
        self.stats["mag_nis"] = y * y / s
        self.stats["mag_innov_deg"] = math.degrees(y)
        self.q = quat_unit(quat_mul(quat_exp(0.0, 0.0, k * y), self.q))
