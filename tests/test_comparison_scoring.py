"""The live pipeline reads an estimator's attitude in one compiled call, and the comparison
scores a reference with the compiled error function and finds the two estimates around it from
the newest back: the same numbers as the readable `quat_to_euler` and `attitude_error` over a
bisection, bit for bit, however far back the reference lies."""

from __future__ import annotations

import math

import numpy as np

from gcs.core.comparison import SCAN_BACK, Comparison, attitude_error
from gcs.core.estimators import registry
from gcs.core.estimators.kernels import Q
from gcs.core.estimators.kernels import attitude_error as compiled_attitude_error
from gcs.core.rotation import euler_quat, quat_to_euler
from gcs.core.samples import AttitudeSample, ImuSample


def unit(v: np.ndarray) -> tuple[float, float, float, float]:
    w, x, y, z = (v / np.linalg.norm(v)).tolist()
    return w, x, y, z


def test_compiled_error_equals_the_python_one_bit_for_bit():
    rng = np.random.default_rng(3)
    cases = []
    for _ in range(20_000):
        q0 = rng.normal(size=4)
        step = rng.normal(size=4) * 10 ** rng.uniform(-7, 0)  # nearly equal (linear) to far apart (slerp)
        ref = rng.uniform(-math.pi, math.pi, 3).tolist()
        cases.append((unit(q0), unit(q0 + step), float(rng.uniform()), *ref))
    q = unit(rng.normal(size=4))
    minus_q = (-q[0], -q[1], -q[2], -q[3])
    cases += [
        (q, q, 0.0, 0.0, 0.0, 0.0),
        (q, minus_q, 0.5, math.pi, -math.pi, math.pi),  # the same attitude the other way round
        (euler_quat(0.1, math.pi / 2, 0.3), euler_quat(0.1, math.pi / 2 - 1e-9, 0.3), 1.0, 0.1, 1.5, 0.3),
        (euler_quat(math.pi, 0.0, math.pi), euler_quat(-math.pi + 1e-6, 0.0, -math.pi), 0.5, -math.pi, 0.0, math.pi),
    ]
    for case in cases:
        assert compiled_attitude_error(*case) == attitude_error(*case), case


def test_a_late_reference_is_scored_against_the_estimates_around_it():
    rng = np.random.default_rng(5)
    c = Comparison(window=100.0, history=100.0)
    times = np.cumsum(rng.uniform(0.002, 0.004, 2000)).tolist()
    quats = [euler_quat(*rng.normal(0.0, 0.5, 3).tolist()) for _ in times]
    for t, q in zip(times, quats, strict=True):
        c.add_estimate(t, q)
    # references 0.5, 1.5, 20, 200 and 1999 estimates back of the newest, and one past it
    for back in (1, 2, 21, SCAN_BACK + 5, 201, 1999):
        i = len(times) - 1 - back
        t = times[i] + 0.3 * (times[i + 1] - times[i])
        c.add_reference(AttitudeSample(t, 0.1, -0.2, 0.3, "onboard"))
        u = (t - times[i]) / (times[i + 1] - times[i])
        want = attitude_error(quats[i], quats[i + 1], u, 0.1, -0.2, 0.3)
        assert c.stats["onboard"].recent[-1] == (t, *want), back
    c.add_reference(AttitudeSample(times[-1], 0.1, -0.2, 0.3, "onboard"))
    assert c.stats["onboard"].recent[-1][1:] == attitude_error(quats[-1], quats[-1], 0.0, 0.1, -0.2, 0.3)


def test_an_estimators_compiled_attitude_equals_its_quaternion_and_the_python_angles():
    rng = np.random.default_rng(11)
    est = registry.create("ekf")
    gyro, accel, mag = np.array([0.3, -0.2, 0.5]), np.array([0.5, -0.3, -9.7]), np.array([0.2, 0.05, 0.4])
    for k in range(2000):
        est.update_imu(ImuSample(0.0025 * k, gyro + rng.normal(0, 0.5, 3), accel + rng.normal(0, 0.5, 3), mag))
        q, euler = est.attitude()
        assert q == tuple(est.quaternion.tolist())
        assert euler == quat_to_euler(q)
    for q in ((1.0, 0.0, 0.0, 0.0), unit(np.array([0.5, 0.5, 0.5, 0.5])), unit(np.array([0.7, 0.0, 0.7, 1e-9]))):
        est.s[Q : Q + 4] = q
        assert est.attitude() == (q, quat_to_euler(q))
