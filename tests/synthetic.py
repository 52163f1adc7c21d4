"""Noise-free IMU samples of known attitude trajectories, for the estimator tests."""

from __future__ import annotations

import numpy as np

from gcs.core.rotation import euler_to_quat, quat_from_rotvec, quat_multiply, quat_to_matrix
from gcs.core.samples import G0, ImuSample

G_NED = np.array([0.0, 0.0, G0])
#: An earth field of 0.5 gauss, 60° dip, pointing to magnetic north.
MAG_NED = np.array([0.25, 0.0, 0.433])
#: A z-up sensor frame (BROAD-like): sensor vector = Z_UP @ body FRD vector.
Z_UP = np.diag([1.0, -1.0, -1.0])


def imu(t, q, gyro=(0.0, 0.0, 0.0), a_ned=(0.0, 0.0, 0.0), mag=True, frame=np.eye(3)) -> ImuSample:
    """The sample a perfect IMU at attitude q (body → NED) gives, expressed in `frame`."""
    R = quat_to_matrix(q)
    f = R.T @ (np.asarray(a_ned, dtype=float) - G_NED)
    m = R.T @ MAG_NED
    return ImuSample(t, frame @ np.asarray(gyro, dtype=float), frame @ f, frame @ m if mag else None, "synthetic")


def static(roll, pitch, yaw, rate=100.0, duration=5.0, t0=0.0, **kw) -> list[ImuSample]:
    q = euler_to_quat(roll, pitch, yaw)
    return [imu(t0 + k / rate, q, **kw) for k in range(int(duration * rate))]


def spinning(q0, omega, rate=100.0, duration=5.0, **kw):
    """Samples and true attitudes of a body turning at constant body rate omega (rad/s)."""
    samples, truth = [], []
    for k in range(int(duration * rate)):
        t = k / rate
        q = quat_multiply(q0, quat_from_rotvec(np.asarray(omega) * t))
        samples.append(imu(t, q, gyro=omega, **kw))
        truth.append(q)
    return samples, truth


def angle_between(q1, q2) -> float:
    """Rotation angle (deg) between two attitudes."""
    d = abs(float(np.dot(q1, q2)))
    return float(np.degrees(2 * np.arccos(min(1.0, d))))
