"""The live pipeline reads an estimator's attitude in one compiled call, and the comparison
scores a reference with the compiled error function and finds the two estimates around it from
the newest back: the same numbers as the readable `quat_to_euler` and `attitude_error` over a
bisection, bit for bit, however far back the reference lies."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gcs.core.comparison import SCAN_BACK, Comparison, attitude_error
from gcs.core.comparison_compiled import CompiledComparison
from gcs.core.estimators import registry
from gcs.core.estimators.kernels import Q
from gcs.core.estimators.kernels import attitude_error as compiled_attitude_error
from gcs.core.rotation import euler_quat, quat_to_euler
from gcs.core.samples import REBOOT_CLOCK_JUMP, AttitudeSample, ImuSample


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
    # references 0.5, 1.5, 20, 200 and 300 estimates back of the newest (under a second: more is a
    # new boot's reference, test_a_reference_a_reboot_behind_starts_the_new_boot), and one past it
    for back in (1, 2, 21, SCAN_BACK + 5, 201, 301):
        i = len(times) - 1 - back
        t = times[i] + 0.3 * (times[i + 1] - times[i])
        c.add_reference(AttitudeSample(t, 0.1, -0.2, 0.3, "onboard"))
        u = (t - times[i]) / (times[i + 1] - times[i])
        want = attitude_error(quats[i], quats[i + 1], u, 0.1, -0.2, 0.3)
        assert c.stats["onboard"].recent[-1] == (t, *want), back
    c.add_reference(AttitudeSample(times[-1], 0.1, -0.2, 0.3, "onboard"))
    assert c.stats["onboard"].recent[-1][1:] == attitude_error(quats[-1], quats[-1], 0.0, 0.1, -0.2, 0.3)


def test_a_reference_a_reboot_behind_starts_the_new_boot():
    """A reference more than REBOOT_CLOCK_JUMP behind the newest estimate is a rebooted vehicle's
    (its first ATTITUDE comes before its first IMU sample): not scored against the old boot's
    estimates at its time, but kept for the new boot's, as at the start of a session."""
    for c in (Comparison(), CompiledComparison()):
        for k in range(1000):  # 20 s at 50 Hz
            c.add_estimate(0.02 * k, (1.0, 0.0, 0.0, 0.0))
        c.add_reference(AttitudeSample(19.98 - REBOOT_CLOCK_JUMP + 0.01, 0.0, 0.0, 0.0, "onboard"))  # late
        assert c.summary()["references"]["onboard"]["session"]["n"] == 1, type(c)
        c.add_reference(AttitudeSample(10.0, 0.5, 0.0, 0.0, "onboard"))  # the old boot's estimates cover 10 s
        assert c.summary()["references"]["onboard"]["session"]["n"] == 1, type(c)
        c.add_estimate(10.0, euler_quat(0.5, 0.0, 0.0))  # the new boot's first estimate: as its reference
        summary = c.summary()
        assert summary["references"]["onboard"]["session"]["n"] == 2, type(c)
        assert summary["references"]["onboard"]["session"]["max"] == pytest.approx([0.0] * 3, abs=1e-9), type(c)
        assert summary["dropped"] == 0, type(c)


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
