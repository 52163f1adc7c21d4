"""Truth motion scripts: rates, accelerations and attitudes that agree with each other."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gcs.core.rotation import quat_conjugate, quat_from_rotvec, quat_multiply, quat_normalize
from gcs.sim.motion import GRAVITY, SCRIPTS, make_script


def angle_between(q1, q2) -> float:
    """Rotation angle (rad) between two attitudes."""
    e = quat_multiply(quat_conjugate(q1), q2)
    return 2 * math.acos(min(1.0, abs(e[0])))


@pytest.mark.parametrize("name", sorted(SCRIPTS))
def test_integrating_the_truth_gyro_reproduces_the_truth_attitude(name):
    script = make_script(name)
    dt = 0.004
    q = script.truth(0.0).q
    worst = 0.0
    for k in range(int(script.period / dt)):
        omega = script.truth((k + 0.5) * dt).omega_body  # midpoint rule
        q = quat_normalize(quat_multiply(q, quat_from_rotvec(omega * dt)))
        if k % 250 == 0:
            worst = max(worst, angle_between(q, script.truth((k + 1) * dt).q))
    assert math.degrees(worst) < 0.01


@pytest.mark.parametrize("name", sorted(SCRIPTS))
def test_acceleration_and_velocity_are_derivatives_and_the_script_loops(name):
    script = make_script(name)
    h = 1e-4
    for t in np.linspace(0.05, script.period - 0.05, 400):
        now = script.truth(t)
        dv = (script.truth(t + h).vel_ned - script.truth(t - h).vel_ned) / (2 * h)
        dp = (script.truth(t + h).pos - script.truth(t - h).pos) / (2 * h)
        assert dv == pytest.approx(now.accel_ned, abs=1e-5)
        assert dp == pytest.approx(now.vel_ned, abs=0.01)  # circuit: tabulated position
        R = now.rotation
        assert R.T @ (now.accel_ned - [0, 0, GRAVITY]) == pytest.approx(now.specific_force, abs=1e-9)
    start, lap = script.truth(0.0), script.truth(script.period * 3)
    assert angle_between(start.q, lap.q) < 1e-9
    assert lap.pos == pytest.approx(start.pos, abs=1e-6)


def test_bench_reaches_and_holds_the_thesis_angles():
    script = make_script("bench")
    times = np.arange(0.0, script.period, 0.05)
    euler = np.degrees([script.truth(t).euler for t in times])

    def held(axis: int, target: float) -> float:
        """Seconds the axis spends within 0.01° of target with the other two axes level."""
        others = [i for i in range(3) if i != axis]
        on = (np.abs(euler[:, axis] - target) < 0.01) & np.all(np.abs(euler[:, others]) < 0.01, axis=1)
        return on.sum() * 0.05

    for target in (-30, -45, -60):
        assert held(0, target) >= 4.5
    for target in (30, 45, 60):
        assert held(1, target) >= 4.5
    for target in (-30, -45, 60):
        assert held(2, target) >= 4.5
    assert all(np.allclose(script.truth(t).pos, 0) and np.allclose(script.truth(t).vel_ned, 0) for t in times)


def test_quad_turns_are_coordinated_and_it_pitches_to_accelerate():
    script = make_script("quad")
    cruise = script.truth(0.5 * (script.t_cruise + script.t_brake))
    v = np.linalg.norm(cruise.vel_ned[:2])
    assert v == pytest.approx(8.0)
    assert math.tan(cruise.euler[0]) == pytest.approx(v * v / (script.radius * GRAVITY))
    assert cruise.euler[1] == pytest.approx(0.0, abs=1e-9)
    for t in np.linspace(0, script.period, 2000):
        f = script.truth(t).specific_force
        assert abs(f[1]) < 1e-9 and abs(f[0]) < 1e-9  # thrust only: no side or forward force
    speeding_up = script.truth(script.t_go + 0.5 * script.ramp)
    assert speeding_up.euler[1] < math.radians(-10)  # nose down to accelerate
    braking = script.truth(script.t_brake + 0.5 * script.ramp)
    assert braking.euler[1] > math.radians(10)
    assert max(-script.truth(t).pos[2] for t in np.linspace(0, script.period, 200)) == pytest.approx(10.0)


def test_circuit_is_a_car_on_a_closed_loop():
    script = make_script("circuit")
    truths = [script.truth(t) for t in np.linspace(0, script.period, 3000)]
    speeds = [np.linalg.norm(s.vel_ned) for s in truths]
    assert speeds == pytest.approx([3.0] * len(speeds))
    roll = np.degrees([s.euler[0] for s in truths])
    pitch = np.degrees([s.euler[1] for s in truths])
    assert roll.max() == pytest.approx(22) and roll.min() == pytest.approx(-22)
    assert pitch.max() == pytest.approx(16) and pitch.min() == pytest.approx(-16)
    yaw_turned = sum(abs(math.remainder(b.euler[2] - a.euler[2], 2 * math.pi)) for a, b in zip(truths, truths[1:]))
    assert math.degrees(yaw_turned) == pytest.approx(360, abs=0.5)
    extent = np.ptp([s.pos[:2] for s in truths], axis=0)
    assert extent.min() > 20  # a real circuit, not a point
