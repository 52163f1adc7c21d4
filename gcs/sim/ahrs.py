"""The simulated autopilot's own attitude estimate (what its ATTITUDE / AHRS2 report).

Real firmware reports its estimate, never the truth, so a ground station comparing estimators
must see realistic small errors and lag. This is a Mahony complementary filter in plain floats,
run at the autopilot loop rate on the vehicle's own noisy sensors, the way ArduPilot's DCM works:
gyro integration, roll/pitch pulled toward the accelerometer's gravity after removing the
vehicle's own acceleration (from GPS velocity differences, as DCM does), heading pulled toward the
tilt-compensated compass, and an integral term that learns the gyro bias. It is not the ground
station's estimator (gcs.core.estimators); it only has to behave like an autopilot's.
"""

from __future__ import annotations

import math

from gcs.core.rotation import quat_to_euler, wrap_pi


class OnboardAhrs:
    """Attitude as a quaternion (w, x, y, z) body FRD → NED.

    kp: roll/pitch correction gain, 1/s (ArduPilot AHRS_RP_P).  kp_yaw: heading gain, 1/s
    (AHRS_YAW_P).  ki: gyro-bias learning gain, 1/s².  declination: rad, added to the compass
    heading to get true heading (ArduPilot COMPASS_DEC).
    """

    def __init__(self, kp: float, kp_yaw: float, ki: float, declination: float) -> None:
        self.kp, self.kp_yaw, self.ki, self.declination = kp, kp_yaw, ki, declination
        self.q = [1.0, 0.0, 0.0, 0.0]
        self.bias = [0.0, 0.0, 0.0]
        self.rate = (0.0, 0.0, 0.0)
        self.error_rp = 0.0
        self.error_yaw = 0.0
        self._t: float | None = None

    def update(self, t: float, gyro, accel, mag, accel_ned) -> None:
        """Fuse one sample at vehicle time t (s): gyro rad/s, accel m/s², mag gauss (body FRD),
        accel_ned m/s²: the vehicle's acceleration from GPS velocity differences (or zeros)."""
        dt = 0.0 if self._t is None else t - self._t
        self._t = t
        w, x, y, z = self.q
        # R (body→NED); row 2 is "down" seen in the body.
        r00, r01, r02 = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
        r10, r11, r12 = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
        r20, r21, r22 = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
        gx, gy, gz = (gyro[i] - self.bias[i] for i in range(3))
        # Gravity measured in the body: Rᵀg = Rᵀa − f (f = specific force from the accelerometer).
        an, ae, ad = accel_ned
        mx_ = r00 * an + r10 * ae + r20 * ad - accel[0]
        my_ = r01 * an + r11 * ae + r21 * ad - accel[1]
        mz_ = r02 * an + r12 * ae + r22 * ad - accel[2]
        norm = math.sqrt(mx_ * mx_ + my_ * my_ + mz_ * mz_)
        ex = ey = ez = 0.0
        if norm > 1e-6:
            mx_, my_, mz_ = mx_ / norm, my_ / norm, mz_ / norm
            # e = measured × estimated turns the estimate toward the measurement.
            ex, ey, ez = my_ * r22 - mz_ * r21, mz_ * r20 - mx_ * r22, mx_ * r21 - my_ * r20
        self.error_rp = math.sqrt(ex * ex + ey * ey + ez * ez)
        # Heading: field azimuth in the estimated earth frame should equal the declination.
        hn = r00 * mag[0] + r01 * mag[1] + r02 * mag[2]
        he = r10 * mag[0] + r11 * mag[1] + r12 * mag[2]
        yaw_error = 0.0
        if hn or he:
            yaw_error = wrap_pi(self.declination - math.atan2(he, hn))
        self.error_yaw = abs(yaw_error)
        cx = self.kp * ex + self.kp_yaw * yaw_error * r20
        cy = self.kp * ey + self.kp_yaw * yaw_error * r21
        cz = self.kp * ez + self.kp_yaw * yaw_error * r22
        if dt > 0:
            self.bias[0] -= self.ki * (ex + yaw_error * r20) * dt
            self.bias[1] -= self.ki * (ey + yaw_error * r21) * dt
            self.bias[2] -= self.ki * (ez + yaw_error * r22) * dt
        self.rate = (gx, gy, gz)
        if dt <= 0:
            return
        # q ← q ⊗ exp(½ ω dt), first order, then renormalise.
        ox, oy, oz = (gx + cx) * 0.5 * dt, (gy + cy) * 0.5 * dt, (gz + cz) * 0.5 * dt
        nw = w - x * ox - y * oy - z * oz
        nx = x + w * ox + y * oz - z * oy
        ny = y - x * oz + w * oy + z * ox
        nz = z + x * oy - y * ox + w * oz
        n = math.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
        self.q = [nw / n, nx / n, ny / n, nz / n]

    def euler(self) -> tuple[float, float, float]:
        """(roll, pitch, yaw) rad, Z-Y-X."""
        return quat_to_euler(self.q)
