"""Behaviour every registered estimator must have: initialisation, convergence, any right-handed
sensor frame, constant-rate integration, live gain changes, gaps, health."""

import math
from dataclasses import replace

import numpy as np
import pytest
from synthetic import Z_UP, angle_between, imu, spinning, static

from gcs.core.estimators import registry
from gcs.core.estimators.base import FIELD_WAIT
from gcs.core.rotation import euler_to_quat, matrix_to_quat, quat_to_euler, quat_to_matrix

NAMES = registry.names()
D = math.radians


def run(est, samples):
    out = []
    for s in samples:
        est.update_imu(s)
        out.append(est.quaternion)
    return out


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("axis", ["roll", "pitch"])
@pytest.mark.parametrize("angle", [-60, -45, -30, 30, 45, 60])
def test_static_tilt_converges_from_level(name, axis, angle):
    """Initialised level, then held at a tilt with no rotation rate: the drift correction must
    bring the estimate to the true tilt within 0.5°."""
    roll, pitch = (D(angle), 0.0) if axis == "roll" else (0.0, D(angle))
    est = registry.create(name)
    est.update_imu(imu(0.0, euler_to_quat(0.0, 0.0, D(20))))
    run(est, static(roll, pitch, D(20), rate=50, duration=120, t0=0.02))
    est_roll, est_pitch, _ = quat_to_euler(est.quaternion)
    assert abs(est_roll - roll) < D(0.5) and abs(est_pitch - pitch) < D(0.5)


@pytest.mark.parametrize("name", NAMES)
def test_initialises_from_first_sample(name):
    est = registry.create(name)
    assert est.update_imu(static(D(30), D(-45), D(120), duration=0.01)[0])
    assert angle_between(est.quaternion, euler_to_quat(D(30), D(-45), D(120))) < 0.01
    assert est.health()["last_reinit"] == "first sample"


@pytest.mark.parametrize("name", NAMES)
def test_a_start_without_a_field_waits_for_one(name):
    """ArduPilot's first RAW_IMU after a boot carry no field (its compass not read yet) and the
    ones that bring the first field a boot jolt (ArduPlane SITL: 0.3 g along x): the start is held
    (not valid, not counted) until the field comes, then takes the tilt of the first sample carried
    by the gyro and the field's heading over it (the jolt taken as gravity would be 17° of tilt).
    Before, every estimator started at the first sample with a made-up heading of 0° (120° off
    here) and was still 120° (dcm), 119° (kf) and 6° (ekf) off at the field's sample."""
    samples, truth = spinning(euler_to_quat(D(5), D(-3), D(120)), [0.2, -0.1, 0.5], rate=50, duration=1)
    fieldless = [replace(s, mag=None) for s in samples[:5]]
    jolt = replace(samples[5], accel=samples[5].accel + np.array([3.0, 0.0, 0.0]))
    est = registry.create(name)
    assert not any(est.update_imu(s) for s in fieldless)
    assert est.update_imu(jolt)
    assert angle_between(est.quaternion, truth[5]) < 0.1
    h = est.health()
    assert h["reinit_count"] == 1 and h["last_reinit"] == "first sample"


@pytest.mark.parametrize("name", NAMES)
def test_a_source_without_a_field_starts_after_the_wait(name):
    """No magnetometer at all: the estimator starts FIELD_WAIT s after the first sample, level as
    the samples say."""
    samples = [replace(s, mag=None) for s in static(D(10), D(5), D(40), rate=50, duration=2)]
    est = registry.create(name)
    first = [est.update_imu(s) for s in samples].index(True)
    assert samples[first].t - samples[0].t == pytest.approx(FIELD_WAIT, abs=0.021)
    roll, pitch, _ = quat_to_euler(est.quaternion)
    assert abs(roll - D(10)) < D(0.5) and abs(pitch - D(5)) < D(0.5)
    assert est.health()["reinit_count"] == 1


@pytest.mark.parametrize("name", NAMES)
def test_any_right_handed_sensor_frame(name):
    """A z-up sensor (BROAD-like: +9.81 on the up axis at rest) gives q sensor → NED."""
    q_body = euler_to_quat(D(10), D(-20), D(75))
    q_sensor = matrix_to_quat(quat_to_matrix(q_body) @ Z_UP.T)
    est = registry.create(name)
    q = run(est, static(D(10), D(-20), D(75), duration=5, frame=Z_UP))[-1]
    assert angle_between(q, q_sensor) < 0.5


@pytest.mark.parametrize("name", NAMES)
def test_constant_rotation_rate_matches_closed_form(name):
    """q(t) = q0 ⊗ exp(ω t / 2); includes a full yaw turn through ±180°."""
    samples, truth = spinning(euler_to_quat(D(20), D(10), D(170)), [0.3, -0.2, 1.5], rate=100, duration=5)
    est = registry.create(name)
    out = run(est, samples)
    assert max(angle_between(a, b) for a, b in zip(out, truth)) < 0.5


@pytest.mark.parametrize("name", NAMES)
def test_gain_change_mid_run_is_continuous(name):
    """Every gain changed on a moving vehicle: no output jump beyond the motion of one step."""
    samples, _ = spinning(euler_to_quat(D(10), D(5), D(30)), [0.2, 0.1, 0.5], rate=100, duration=4)
    est = registry.create(name)
    out = run(est, samples[:200])
    step = max(angle_between(a, b) for a, b in zip(out[100:], out[101:]))
    for g in est.GAINS:
        new = min(g.max, g.default * 2) if g.default else (g.min + g.max) / 4
        est.set_gain(g.name, new)
        assert est.gains[g.name] == new
    after = run(est, samples[200:205])
    assert angle_between(out[-1], after[0]) < step + 0.2


@pytest.mark.parametrize("name", NAMES)
def test_duplicates_clock_back_and_gaps(name):
    est = registry.create(name)
    samples = static(D(10), D(5), D(40), duration=2)
    run(est, samples)
    q = est.quaternion
    assert est.update_imu(samples[-1])  # duplicate: ignored
    assert est.health()["duplicates"] == 1 and angle_between(q, est.quaternion) < 1e-9
    est.update_imu(static(D(-20), 0.0, 0.0, t0=1.0, duration=0.01)[0])  # clock back (reboot)
    h = est.health()
    assert "clock went back" in h["last_reinit"] and h["reinit_count"] == 2
    assert angle_between(est.quaternion, euler_to_quat(D(-20), 0.0, 0.0)) < 0.01  # re-initialised
    est.update_imu(static(D(30), 0.0, 0.0, t0=5.0, duration=0.01)[0])  # 4 s gap
    assert "gap of 4.000 s" in est.health()["last_reinit"]
    assert angle_between(est.quaternion, euler_to_quat(D(30), 0.0, 0.0)) < 0.01


@pytest.mark.parametrize("name", NAMES)
def test_health_and_unit_quaternion(name):
    est = registry.create(name)
    run(est, static(D(5), D(5), D(5), duration=1))
    h = est.health()
    assert h["accel_norm"] == pytest.approx(9.80665)
    assert abs(np.linalg.norm(est.quaternion) - 1) < 1e-9


@pytest.mark.parametrize("name", NAMES)
def test_declination_gives_true_north(name):
    est = registry.create(name, declination=D(12.5))
    q = run(est, static(0.0, 0.0, D(40), duration=1))[-1]  # magnetic heading 40°
    assert angle_between(q, euler_to_quat(0.0, 0.0, D(52.5))) < 0.5


def test_unknown_names_are_reported():
    with pytest.raises(KeyError, match="known: dcm"):
        registry.get("nope")
