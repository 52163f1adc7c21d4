"""Premerlani–Bizard direction-cosine-matrix attitude filter, as in seed 000 (Bermúdez & Niño
2014, §3 and Annex A) and ArduPilot's AP_AHRS_DCM, fixed where the thesis code is wrong."""

from __future__ import annotations

import math

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
    initial_attitude,
)
from gcs.core.estimators.magnetic import MAG_GAINS, MAG_OFF, MagneticHeading
from gcs.core.estimators.rest import REST_GAINS, REST_OFF, RestBias
from gcs.core.gains import Gain
from gcs.core.rotation import Rows, Vec3, matrix_to_quat, vec3
from gcs.core.samples import G0, GpsSample, ImuSample

#: Spin rate above which the integrator freezes (AP_AHRS_DCM SPIN_RATE_LIMIT, 20 deg/s).
SPIN_RATE_LIMIT = math.radians(20.0)
#: Largest gyro bias the integrator may learn, per axis (rad/s); keeps a bad reference from winding it up.
OMEGA_I_MAX = 0.1


def renormalize(X: Vec3, Y: Vec3) -> tuple[Vec3, Vec3, Vec3, float]:
    """Seed 000 eqs. (13)-(17) on the first two rows X, Y of R (3-tuples of floats).

    error = X·Y (13) is split half to each row (14)-(15), Z = X_orth × Y_orth (16), and each row is
    scaled by the first-order Taylor form of 1/|v|, ½(3 - v·v) (17). Returns the new rows and the
    largest |1 - v·v| seen, the renormalisation size reported in health.
    """
    x0, x1, x2 = X
    y0, y1, y2 = Y
    err = 0.5 * (x0 * y0 + x1 * y1 + x2 * y2)
    x0, x1, x2, y0, y1, y2 = x0 - err * y0, x1 - err * y1, x2 - err * y2, y0 - err * x0, y1 - err * x1, y2 - err * x2
    z0, z1, z2 = x1 * y2 - x2 * y1, x2 * y0 - x0 * y2, x0 * y1 - x1 * y0
    nx = x0 * x0 + x1 * x1 + x2 * x2
    ny = y0 * y0 + y1 * y1 + y2 * y2
    nz = z0 * z0 + z1 * z1 + z2 * z2
    sx, sy, sz = 0.5 * (3.0 - nx), 0.5 * (3.0 - ny), 0.5 * (3.0 - nz)
    size = max(abs(1.0 - nx), abs(1.0 - ny), abs(1.0 - nz))
    return (x0 * sx, x1 * sx, x2 * sx), (y0 * sy, y1 * sy, y2 * sy), (z0 * sz, z1 * sz, z2 * sz), size


def rotate_rows(rows: Rows, wx: float, wy: float, wz: float) -> tuple[Vec3, ...]:
    """R · exp([w]×) for a body rotation vector w (rad): Rodrigues' exact form of eqs. (11)-(12)."""
    a2 = wx * wx + wy * wy + wz * wz
    if a2 < 1e-12:
        s, c = 1.0 - a2 / 6.0, 0.5 - a2 / 24.0
    else:
        a = math.sqrt(a2)
        s, c = math.sin(a) / a, (1.0 - math.cos(a)) / a2
    # M = I + s[w]x + c[w]x²; [w]x² = w wᵀ - a² I
    m00, m11, m22 = 1.0 + c * (wx * wx - a2), 1.0 + c * (wy * wy - a2), 1.0 + c * (wz * wz - a2)
    m01, m10 = c * wx * wy - s * wz, c * wx * wy + s * wz
    m02, m20 = c * wx * wz + s * wy, c * wx * wz - s * wy
    m12, m21 = c * wy * wz - s * wx, c * wy * wz + s * wx
    return tuple(
        (r0 * m00 + r1 * m10 + r2 * m20, r0 * m01 + r1 * m11 + r2 * m21, r0 * m02 + r1 * m12 + r2 * m22)
        for r0, r1, r2 in rows
    )


class DcmEstimator(AttitudeEstimator):
    """Direction cosine matrix filter with PI drift correction (Premerlani & Bizard 2009).

    R (sensor → NED) ← R·exp([ω dt]×), ω = ½(g_prev + g) + ω_I + ω_P + ω_Y, renormalised (eqs. 13-17); the
    roll-pitch error compares the earth-frame averaged specific force with (0, 0, −g) + GPS dv/dt, the yaw
    error uses the tilt-compensated magnetometer (else the GPS course); PI gains as AP_AHRS_DCM's, with the
    seed 000 code's unit and timing bugs fixed. Presets `ardupilot` (default) and `seed000` (thesis gains).
    Derivation, deviations from seed 000 and AP_AHRS_DCM, gains: docs/estimators/dcm.md
    """

    name = "dcm"
    GAINS = (
        (
            Gain("kp_rp", 0.2, 0.0, 50.0, "1/s", "roll-pitch proportional gain (AHRS_RP_P)"),
            Gain("ki_rp", 0.0087, 0.0, 10.0, "1/s²", "roll-pitch integral gain (gyro bias learning)"),
            Gain("kp_yaw", 0.4, 0.0, 50.0, "1/s", "yaw proportional gain (AHRS_YAW_P)"),
            Gain("ki_yaw", 0.01, 0.0, 10.0, "1/s²", "yaw integral gain"),
            Gain("spin_gain", 1.0, 0.0, 1.0, "", "1 = roll-pitch P gain × clip(spin/50 deg/s, 1, 10)"),
            Gain("spin_gain_yaw", 0.0, 0.0, 1.0, "", "1 = scale the yaw P gain with spin rate too (ArduPilot does)"),
            Gain("accel_tau", 1.0, 0.0, 10.0, "s", "earth-frame average of the specific force"),
            Gain("accel_weight", 1.0, 0.0, 1.0, "", "1 = roll-pitch weight clip(1 - 2|1 - |f_avg|/g|, 0, 1)"),
            Gain(
                "accel_dev_gate",
                7.0,
                0.0,
                1000.0,
                "m/s²",
                "roll-pitch P gain × 1/(1 + mean(|f| - g)² / this²); 0 = off",
            ),
            Gain("yaw_spin_half", 2.5, 0.0, 1000.0, "rad/s", "yaw P gain × 1/(1 + (|gyro| / this)²); 0 = off"),
            Gain(
                "yaw_acc_cap",
                0.4,
                0.0,
                1000.0,
                "m²/s⁵",
                "yaw P gain at most this × (1 + (|gyro| / yaw_spin_half)²) / mean(|f| - g)²; 0 = off",
            ),
        )
        + MAG_GAINS
        + REST_GAINS
        + PICK_GAINS
        + SHOCK_GAINS
        + GPS_GAINS
        + COMMON_GAINS
    )
    PRESETS = {
        "ardupilot": {},
        "seed000": {
            "kp_rp": 27.8,
            "kp_yaw": 41.7,
            "ki_rp": 1.0,
            "ki_yaw": 1.5,
            "spin_gain": 0.0,
            "accel_tau": 0.0,
            "accel_weight": 0.0,
            "accel_dev_gate": 0.0,
            "yaw_spin_half": 0.0,
            "yaw_acc_cap": 0.0,
            "pick_dt": 0.0,
            **MAG_OFF,
            **REST_OFF,
        },
    }
    DEFAULT_PRESET = "ardupilot"

    def __init__(self, preset: str | None = None, **gains: float) -> None:
        super().__init__(preset, **gains)
        self.gps = GpsAcceleration()
        self.rows: Rows = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
        self._reset_correction((0.0, 0.0, 0.0))
        self.valid = False
        self.accel_norm = 0.0
        self.renorm_size = 0.0
        self.renorm_max = 0.0
        self.error_rp = 0.0
        self.error_yaw = 0.0
        self.yaw_source = "none"
        self.mag_rejected = 0

    def _reset_correction(self, gyro: Vec3) -> None:
        self.omega_I = [0.0, 0.0, 0.0]
        self.omega_P = (0.0, 0.0, 0.0)
        self.omega_Y = (0.0, 0.0, 0.0)
        self.gyro_prev = gyro
        self.corr_e = (0.0, 0.0, 0.0)  # R·(ω_P + ω_Y): the P correction as an earth-frame rate
        self.f_avg: tuple[float, float, float] | None = None  # earth-frame specific force, averaged
        self.r_avg = (0.0, 0.0, -G0)  # its reference (gravity + GPS acceleration), averaged alike
        self.accel_w = 1.0
        self.accel_dev = 0.0  # (|f| - g)², averaged over accel_tau
        self.mag = MagneticHeading()
        self.shock = Shock()
        self.rest = RestBias()

    def update_gps(self, sample: GpsSample) -> None:
        self.gps.update(sample)

    def update_imu(self, sample: ImuSample) -> bool:
        gx, gy, gz = (float(v) for v in sample.gyro)
        fx, fy, fz = (float(v) for v in sample.accel)
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
            R = initial_attitude(force, sample.mag, self.gains["declination"])
            north, east, down = (vec3(float(v) for v in row) for row in R)
            self.rows = (north, east, down)
            self._reset_correction((gx, gy, gz))
            if self.force_carried:  # the average starts at the carried force, not at the next (jolted) sample
                self.f_avg = (0.0, 0.0, -float(np.linalg.norm(force)))
            self.valid = True
            return True
        if dt == 0.0:
            return self.valid
        g = self.gains
        # 1. gyro update with the corrections computed on the previous sample (eq. 27): a log's
        #    interval-mean sample turns alone, picked samples (dt > pick_dt) by their trapezoid
        px, py, pz = self.gyro_prev if dt > g["pick_dt"] else (gx, gy, gz)
        self.gyro_prev = (gx, gy, gz)
        oI, oP, oY = self.omega_I, self.omega_P, self.omega_Y
        wx = 0.5 * (px + gx) + oI[0] + oP[0] + oY[0]
        wy = 0.5 * (py + gy) + oI[1] + oP[1] + oY[1]
        wz = 0.5 * (pz + gz) + oI[2] + oP[2] + oY[2]
        X, Y, _ = rotate_rows(self.rows, wx * dt, wy * dt, wz * dt)
        if self.f_avg is not None:
            # the P corrections just turned the estimate by c·dt in the earth frame (R·ω_P = kp·e):
            # turn the averaged specific force with it, so the average filters the measurement
            # and does not delay the feedback loop (VQF's accLp in the gyro-only frame)
            c0, c1, c2 = self.corr_e
            F = self.f_avg
            self.f_avg = (
                F[0] + (c1 * F[2] - c2 * F[1]) * dt,
                F[1] + (c2 * F[0] - c0 * F[2]) * dt,
                F[2] + (c0 * F[1] - c1 * F[0]) * dt,
            )
        # 2. renormalisation
        X, Y, Z, self.renorm_size = renormalize(X, Y)
        self.renorm_max = max(self.renorm_max, self.renorm_size)
        self.rows = (X, Y, Z)
        spin = math.sqrt(wx * wx + wy * wy + wz * wz)
        if self.shock.update(sample.t, self.accel_norm, math.sqrt(gx * gx + gy * gy + gz * gz), g.values):
            if self.shock.saturated:
                self.mag.distrust_heading()
        # 3. roll-pitch error, earth frame, from the averaged specific force and reference (held
        #    through a shock: the accelerometer then measures the impact, not gravity)
        ex = ey = 0.0
        if self.accel_norm > 1e-6 and not self.shock.active:
            f0 = X[0] * fx + X[1] * fy + X[2] * fz
            f1 = Y[0] * fx + Y[1] * fy + Y[2] * fz
            f2 = Z[0] * fx + Z[1] * fy + Z[2] * fz
            an, ae, ad = self.gps.at(sample.t)
            k = g["gps_gain"]
            r0, r1, r2 = k * an, k * ae, k * ad - G0
            if self.f_avg is not None:  # first-order low-pass: a = dt/(tau + dt); tau = 0 passes through
                a = dt / (g["accel_tau"] + dt)
                F, Q = self.f_avg, self.r_avg
                f0, f1, f2 = F[0] + a * (f0 - F[0]), F[1] + a * (f1 - F[1]), F[2] + a * (f2 - F[2])
                r0, r1, r2 = Q[0] + a * (r0 - Q[0]), Q[1] + a * (r1 - Q[1]), Q[2] + a * (r2 - Q[2])
            self.f_avg, self.r_avg = (f0, f1, f2), (r0, r1, r2)
            nf = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
            nr = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
            if nf > 1e-9 and nr > 1e-9:
                w = 1.0 - g["accel_weight"] * (1.0 - min(max(1.0 - 2.0 * abs(1.0 - nf / nr), 0.0), 1.0))
                self.accel_w = w
                c = w / (nf * nr)
                # (f × r) x and y components; z dropped (yaw belongs to the yaw reference)
                ex = (f1 * r2 - f2 * r1) * c
                ey = (f2 * r0 - f0 * r2) * c
        self.error_rp = math.hypot(ex, ey)
        # body frame: Rᵀ e (e has no z part)
        bx, by, bz = X[0] * ex + Y[0] * ey, X[1] * ex + Y[1] * ey, X[2] * ex + Y[2] * ey
        # 4. yaw error
        ez = self._yaw_error(sample, X, Y, Z, dt, spin)
        self.error_yaw = abs(ez)
        # 5. PI
        s = min(max(spin / math.radians(50.0), 1.0), 10.0)
        kp = g["kp_rp"] * (s if g["spin_gain"] >= 0.5 else 1.0)
        kpy = g["kp_yaw"] * (s if g["spin_gain_yaw"] >= 0.5 else 1.0)
        # 5a. weights: tilt trusts the accelerometer less while |f| departs from g (linear
        #     acceleration); heading trusts the field less while turning fast (its sample's
        #     timing against the gyro's is then worth degrees)
        dev = self.accel_norm - G0
        self.accel_dev += dt / (g["accel_tau"] + dt) * (dev * dev - self.accel_dev)
        gate, half = g["accel_dev_gate"], g["yaw_spin_half"]
        if gate > 0.0:
            kp /= 1.0 + self.accel_dev / (gate * gate)
        turn = 1.0
        if half > 0.0:
            turn += (gx * gx + gy * gy + gz * gz) / (half * half)
            kpy /= turn
        # 5b. and at most yaw_acc_cap·turn/⟨(|f| − g)²⟩ while accelerating: the tilt is then less
        #     sure and each degree of it is tan(dip) degrees of the field's heading. A ceiling, not
        #     a factor, so that kp_yaw tunes the heading loop and not its share in translation;
        #     raised with the turn rate, as a turn's acceleration is mostly centripetal (averaged
        #     out of the tilt reference) and fast turns are where the gyro drifts
        cap = g["yaw_acc_cap"] * turn
        if cap > 0.0 and kpy * self.accel_dev > cap:
            kpy = cap / self.accel_dev
        self.omega_P = (kp * bx, kp * by, kp * bz)
        self.omega_Y = (kpy * ez * Z[0], kpy * ez * Z[1], kpy * ez * Z[2])
        self.corr_e = (kp * ex, kp * ey, kpy * ez)
        if spin < SPIN_RATE_LIMIT and not self.shock.active:
            ki, kiy = g["ki_rp"] * dt, g["ki_yaw"] * ez * dt
            for i, (b, z) in enumerate(((bx, Z[0]), (by, Z[1]), (bz, Z[2]))):
                self.omega_I[i] = min(max(self.omega_I[i] + ki * b + kiy * z, -OMEGA_I_MAX), OMEGA_I_MAX)
        # 6. at rest the gyro reads its bias (−ω_I), heading axis included
        oI = self.omega_I
        gps_acc = self.gps.at(sample.t)
        bias = self.rest.update(sample.t, (gx, gy, gz), (-oI[0], -oI[1], -oI[2]), (fx, fy, fz), gps_acc, dt, g.values)
        self.omega_I = [min(max(-v, -OMEGA_I_MAX), OMEGA_I_MAX) for v in bias]
        return True

    def _yaw_error(self, sample: ImuSample, X: Vec3, Y: Vec3, Z: Vec3, dt: float = 0.0, spin: float = 0.0) -> float:
        """Heading error about earth down (rad, small-angle sine), or 0 without a usable reference."""
        self.yaw_source = "none"
        if sample.mag is not None:
            mx, my, mz = (float(v) for v in sample.mag)
            if self.mag.field((mx, my, mz), (X, Y, Z), dt, spin, self.gains.values) is not None:
                self.yaw_source = "mag"
                return self.mag.weight * math.sin(self.mag.yaw_error)
            self.yaw_source = "mag_rejected"
            self.mag_rejected += 1
        course = self.gps.course_at(sample.t, self.gains["gps_speed_min"])
        if course is not None:
            self.yaw_source = "gps_course"
            return X[0] * math.sin(course) - Y[0] * math.cos(course)
        return 0.0

    @property
    def matrix(self) -> npt.NDArray[np.float64]:
        """R, sensor → NED."""
        return np.array(self.rows)

    @property
    def quaternion(self) -> npt.NDArray[np.float64]:
        return matrix_to_quat(np.array(self.rows))

    def health(self) -> dict[str, HealthValue]:
        return {
            **self._common_health(),
            "valid": self.valid,
            "accel_norm": self.accel_norm,
            "renorm_size": self.renorm_size,
            "renorm_max": self.renorm_max,
            "error_rp": self.error_rp,
            "error_yaw": self.error_yaw,
            "yaw_source": self.yaw_source,
            "omega_I": tuple(self.omega_I),
            "accel_weight": self.accel_w,
            "mag_disturbed": self.mag.disturbed,
            "mag_rejected": self.mag_rejected,
            "mag_offset": self.mag.offset,
            "shocks": self.shock.count,
        }
