"""KF-A: thesis matrices, Q rebuilt for the real interval, yaw wrap, filterpy shapes, real data."""

import math
from pathlib import Path

import numpy as np
import pytest
from broad import broad_rmse
from synthetic import imu, static

from gcs.core.estimation import compare_stream
from gcs.core.estimators.kf import SEED004_Q, SEED004_R, KalmanAttitudeFilter, mag_heading
from gcs.core.rotation import euler_to_quat, quat_to_euler
from gcs.logs.readers import read_samples

HOP = str(Path(__file__).resolve().parents[2] / "shared/data/logs/arducopter-sitl-hop.tlog")
D = math.radians


def test_seed004_preset_is_the_thesis_q_and_r():
    kf = KalmanAttitudeFilter("seed004")
    assert kf.gains["k_q"] == 0.03 and kf.gains["dt_ref"] == 0.004
    assert np.allclose(np.diag(kf._r()), SEED004_R)
    # Q per 4 ms step as printed; rebuilt for a 40 ms telemetry interval it is 10× larger
    assert np.allclose(np.diag(kf._q(0.004)), 0.03 * np.array(SEED004_Q))
    assert np.allclose(np.diag(kf._q(0.04)), 0.3 * np.array(SEED004_Q))


def test_model_matrices_follow_the_real_interval():
    kf = KalmanAttitudeFilter()
    kf.update_imu(imu(0.0, euler_to_quat(0, 0, 0)))
    kf.update_imu(imu(0.037, euler_to_quat(0, 0, 0)))
    assert kf.kf.F[0, 3] == pytest.approx(0.037) and kf.kf.B[0, 0] == pytest.approx(0.037**2 / 2)
    assert kf.kf.x.shape == (6, 1)


def test_yaw_innovation_wraps():
    """Heading alternating between +179.8° and −179.8°: the estimate stays at 180°, not 0°."""
    kf = KalmanAttitudeFilter("seed004")
    for k in range(200):
        yaw = D(179.8) if k % 2 else D(-179.8)
        kf.update_imu(imu(k * 0.01, euler_to_quat(0.0, 0.0, yaw)))
        assert abs(abs(kf.euler[2]) - math.pi) < D(1.0)
        assert abs(kf.health()["innovation_yaw"]) < D(1.0)


def test_without_magnetometer_keeps_shapes_and_holds_heading():
    kf = KalmanAttitudeFilter()
    for s in static(D(10), D(-5), 0.0, duration=2, mag=False):
        kf.update_imu(s)
    assert kf.kf.x.shape == (6, 1) and kf.health()["heading_source"] == "none"
    roll, pitch, yaw = quat_to_euler(kf.quaternion)
    assert (roll, pitch, yaw) == pytest.approx((D(10), D(-5), 0.0), abs=D(0.1))


def test_tilt_compensated_heading():
    q = euler_to_quat(D(40), D(-30), D(100))
    s = imu(0.0, q)
    assert mag_heading(s.mag, D(40), D(-30), 0.0) == pytest.approx(D(100))
    assert mag_heading(s.mag, D(40), D(-30), D(10)) == pytest.approx(D(110))


def test_gain_change_takes_effect():
    """r_roll huge: the accelerometer is ignored; back to the default, it is used again."""
    kf = KalmanAttitudeFilter(r_roll=100.0)
    kf.update_imu(imu(0.0, euler_to_quat(0, 0, 0)))
    for s in static(D(20), 0.0, 0.0, rate=50, duration=5, t0=0.02):
        kf.update_imu(s)
    stuck = kf.euler[0]
    assert stuck < D(5)
    kf.set_gain("r_roll", SEED004_R[0])
    for s in static(D(20), 0.0, 0.0, rate=50, duration=60, t0=5.02):
        kf.update_imu(s)
    assert kf.euler[0] == pytest.approx(D(20), abs=D(0.5))


@pytest.mark.slow
def test_sitl_hop_accuracy_vs_simstate():
    """RMS roll/pitch vs SIMSTATE (measured: telemetry 0.30°/0.22°, seed004 1.75°/1.19°)."""

    def rms(preset):
        c = compare_stream(read_samples(HOP), KalmanAttitudeFilter(preset, declination=D(12.5)))
        return c.summary()["references"]["truth"]["session"]["rms"]

    tuned, seed = rms("telemetry"), rms("seed004")
    assert tuned[0] < 1.0 and tuned[1] < 1.0
    assert seed[0] < 2.5 and seed[1] < 2.5
    assert tuned[0] < seed[0] and tuned[1] < seed[1]


def test_roll_innovation_wraps():
    """Roll alternating between +179.8° and −179.8° (a z-up sensor at rest): stays at 180°."""
    kf = KalmanAttitudeFilter()
    for k in range(200):
        roll = D(179.8) if k % 2 else D(-179.8)
        kf.update_imu(imu(k * 0.01, euler_to_quat(roll, D(10), D(30))))
        assert abs(abs(kf.euler[0]) - math.pi) < D(1.0)
        assert abs(kf.health()["innovation_roll"]) < D(1.0)


@pytest.mark.parametrize("preset", ["telemetry", "seed004"])
def test_fast_rotation_through_pitch_90_at_telemetry_rate(preset):
    """500°/s about a level-ish axis through pitch ±90° at 48 Hz: the default integrates the gyro
    exactly and stays within a few degrees; nothing becomes NaN or diverges in either preset."""
    from synthetic import angle_between, spinning

    samples, truth = spinning(euler_to_quat(D(5), 0.0, D(40)), [D(50), D(500), D(30)], rate=48, duration=6)
    kf = KalmanAttitudeFilter(preset)
    err = []
    for s, q in zip(samples, truth):
        kf.update_imu(s)
        assert np.all(np.isfinite(kf.quaternion))
        err.append(angle_between(kf.quaternion, q))
    if preset == "telemetry":
        assert max(err) < 3.0


def test_magnetic_disturbance_is_rejected_and_can_be_switched_off():
    """A magnet adds a field of the earth field's size along sensor x: heading is held (rejected);
    with the seed004 tolerances (off) the heading follows the disturbed field."""
    from synthetic import MAG_NED

    out = {}
    for preset in ("telemetry", "seed004"):
        kf = KalmanAttitudeFilter(preset)
        att = euler_to_quat(0.0, 0.0, D(40))
        for k in range(1000):
            s = imu(k * 0.01, att)
            mag = s.mag + (np.array([np.linalg.norm(MAG_NED), 0.0, 0.0]) if k >= 300 else 0.0)
            kf.update_imu(type(s)(s.t, s.gyro, s.accel, mag, s.source))
        out[preset] = (kf.euler[2], kf.health())
    yaw, h = out["telemetry"]
    assert yaw == pytest.approx(D(40), abs=D(0.5)) and h["mag_disturbed"] and h["heading_source"] == "mag_rejected"
    assert abs(out["seed004"][0] - D(40)) > D(10)


def test_linear_acceleration_inflates_tilt_noise():
    """A sustained 3 m/s² forward acceleration (no GPS): tilt measurement noise is inflated and
    the averaged tilt keeps roll/pitch within a few degrees over 2 s, the thesis R does not."""
    res = {}
    for preset in ("telemetry", "seed004"):
        kf = KalmanAttitudeFilter(preset)
        q = euler_to_quat(0.0, 0.0, 0.0)
        for k in range(200):
            kf.update_imu(imu(k * 0.01, q, a_ned=(3.0 if k >= 100 else 0.0, 0.0, 0.0)))
        res[preset] = (abs(kf.euler[1]), kf.health()["accel_scale"])
    assert res["telemetry"][0] < D(3.0) and res["telemetry"][1] > 1.0
    assert res["seed004"][0] > res["telemetry"][0]


@pytest.mark.parametrize("trial", ["15_undisturbed_fast_translation", "30_disturbed_stationary_magnet"])
def test_broad_robustness_regression(trial):
    """Fast translation and fast rotation near a magnet at 47.6 Hz (RAW_IMU streaming): before the
    exact gyro prediction, averaged tilt, adaptive R and magnetic rejection these scored 49.7° and
    70.4° total RMSE; now about 2.2° and 3.7°."""
    assert broad_rmse(KalmanAttitudeFilter(), trial, 6) < 7.0
