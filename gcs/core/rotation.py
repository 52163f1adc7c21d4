"""Attitude algebra shared by every part: quaternions, rotation matrices, Euler angles.

Conventions (docs/design.md): a quaternion is (w, x, y, z), unit, and rotates body (FRD) vectors
into the earth frame (NED): v_ned = R(q) v_body. Euler angles are Z-Y-X (yaw, pitch, roll), in
radians, as MAVLink ATTITUDE carries them.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np
import numpy.typing as npt

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]
Rows = tuple[Vec3, Vec3, Vec3]
#: A vector or quaternion as plain floats or a numpy array (the formulas only unpack it).
VectorLike = Sequence[float] | npt.NDArray[np.float64]


# --- the formulas, on plain floats (tuples in, tuples out) ---------------------------------------
# Per-sample filter loops call these directly: at 3 and 4 elements numpy's call overhead costs
# more than the arithmetic. The numpy functions further down wrap the same formulas.


def quat_mul(p: VectorLike, q: VectorLike) -> Quat:
    """Hamilton product p ⊗ q (apply q first, then p)."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return (pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw)  # fmt: skip


def quat_exp(x: float, y: float, z: float) -> Quat:
    """Quaternion of a rotation by |(x, y, z)| radians about (x, y, z): exact, also for tiny angles."""
    angle = math.sqrt(x * x + y * y + z * z)
    if angle < 1e-12:
        return 1.0, 0.5 * x, 0.5 * y, 0.5 * z
    s = math.sin(0.5 * angle) / angle
    return math.cos(0.5 * angle), x * s, y * s, z * s


def quat_unit(q: VectorLike) -> Quat:
    """q / |q|."""
    w, x, y, z = q
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return w / n, x / n, y / n, z / n


def quat_rows(q: VectorLike) -> Rows:
    """Rows of the rotation matrix R (body→earth) of a unit quaternion."""
    w, x, y, z = q
    return ((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
            (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
            (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)))  # fmt: skip


def rows_times(R: Rows, a: VectorLike) -> Vec3:
    """R a, for R given as rows."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R
    ax, ay, az = a
    return r00 * ax + r01 * ay + r02 * az, r10 * ax + r11 * ay + r12 * az, r20 * ax + r21 * ay + r22 * az


def euler_quat(roll: float, pitch: float, yaw: float) -> Quat:
    """Quaternion of Z-Y-X Euler angles in radians."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy)  # fmt: skip


def vec3(v: Iterable[float]) -> Vec3:
    """The three components of v as a tuple (ValueError unless there are exactly three)."""
    x, y, z = v
    return x, y, z


# --- numpy API ------------------------------------------------------------------------------------


def quat_multiply(p: npt.NDArray[np.float64], q: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Hamilton product p ⊗ q (apply q first, then p); also element-wise over (4, N) arrays."""
    return np.array(quat_mul(p, q))


def quat_conjugate(q: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    return np.array([q[0], -q[1], -q[2], -q[3]])


def quat_normalize(q: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Unit quaternion with a non-negative scalar part (q and -q are the same rotation)."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q)
    return -q if q[0] < 0 else q


def quat_from_rotvec(v: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Quaternion of a rotation by |v| radians about v (exact, also for tiny angles)."""
    return np.array(quat_exp(float(v[0]), float(v[1]), float(v[2])))


def quat_to_matrix(q: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Rotation matrix R (body→earth) of a unit quaternion."""
    return np.array(quat_rows(q))


def matrix_to_quat(R: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Unit quaternion of a rotation matrix (Shepperd's method, stable for every rotation)."""
    trace = R[0, 0] + R[1, 1] + R[2, 2]
    if trace > 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    return quat_normalize(np.array(q))


def euler_to_quat(roll: float, pitch: float, yaw: float) -> npt.NDArray[np.float64]:
    """Quaternion of Z-Y-X Euler angles in radians."""
    return np.array(euler_quat(roll, pitch, yaw))


def quat_to_euler(q: VectorLike) -> tuple[float, float, float]:
    """Z-Y-X Euler angles (roll, pitch, yaw) in radians, yaw in (-pi, pi]."""
    w, x, y, z = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - x * z))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def wrap_pi(angle: float) -> float:
    """Angle wrapped into (-pi, pi]."""
    a = math.fmod(angle + math.pi, 2 * math.pi)
    if a <= 0:
        a += 2 * math.pi
    return a - math.pi


def wrap_pi_array(angles: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """`wrap_pi` for arrays (into [-pi, pi): the two differ only at exactly ±pi)."""
    wrapped: npt.NDArray[np.float64] = (angles + math.pi) % (2 * math.pi) - math.pi
    return wrapped


def quat_slerp(q0: VectorLike, q1: VectorLike, u: float) -> Quat:
    """Spherical interpolation from unit q0 (u = 0) to unit q1 (u = 1) along the shorter arc,
    normalised. Plain floats, so that kernels.py compiles this same formula for whole runs."""
    w0, x0, y0, z0 = q0
    w1, x1, y1, z1 = q1
    d = w0 * w1 + x0 * x1 + y0 * y1 + z0 * z1
    if d < 0.0:
        w1, x1, y1, z1, d = -w1, -x1, -y1, -z1, -d
    if d > 0.9995:  # nearly equal: normalised linear interpolation is exact to rounding
        a, b = 1.0 - u, u
    else:
        theta = math.acos(min(d, 1.0))
        s = math.sin(theta)
        a, b = math.sin((1.0 - u) * theta) / s, math.sin(u * theta) / s
    w, x, y, z = a * w0 + b * w1, a * x0 + b * x1, a * y0 + b * y1, a * z0 + b * z1
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return w / n, x / n, y / n, z / n
