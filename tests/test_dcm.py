"""DCM: renormalisation, integration, drift correction with GPS acceleration, presets, real data."""

import math
from pathlib import Path

import numpy as np
import pytest
from broad import broad_rmse
from synthetic import imu, spinning, static

from gcs.core.estimation import compare_stream
from gcs.core.estimators.dcm import DcmEstimator, renormalize, rotate_rows
from gcs.core.estimators.magnetic import MAG_OFF
from gcs.core.rotation import euler_to_quat, quat_to_euler
from gcs.core.samples import GpsSample
from gcs.logs.readers import read_samples

HOP = str(Path(__file__).resolve().parents[2] / "shared/data/logs/arducopter-sitl-hop.tlog")
D = math.radians
#: Canberra (the SITL home) magnetic declination: SIMSTATE yaw is true north.
HOP_DECLINATION = D(12.5)


def orthonormality_error(rows) -> float:
    R = np.array(rows)
    return float(np.abs(R.T @ R - np.eye(3)).max())


def test_renormalisation_repairs_a_skewed_matrix():
    rows = ((1.0, 2e-3, 0.0), (1e-3, 0.999, 0.0), (0.0, 0.0, 1.0))
    X, Y = rows[0], rows[1]
    for _ in range(4):
        X, Y, Z, size = renormalize(X, Y)
    assert orthonormality_error((X, Y, Z)) < 1e-12


def test_renormalisation_keeps_orthonormal_over_a_million_steps():
    """10^6 gyro updates + renormalisations, the step functions alone."""
    rows = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    worst = 0.0
    for k in range(1_000_000):
        X, Y, _ = rotate_rows(rows, 0.01 * math.sin(k * 1e-3), 0.02, -0.015 * math.cos(k * 7e-4))
        X, Y, Z, size = renormalize(X, Y)
        rows = (X, Y, Z)
        if k % 100_000 == 0:
            worst = max(worst, orthonormality_error(rows))
    assert max(worst, orthonormality_error(rows)) < 1e-9


@pytest.mark.slow
def test_full_filter_orthonormal_over_1e6_steps():
    """10^6 samples through the whole filter (about 15 s): spinning, corrections active."""
    est = DcmEstimator()
    q0 = euler_to_quat(0.2, -0.1, 1.0)
    samples, _ = spinning(q0, [1.0, -2.0, 3.0], rate=400, duration=2)
    for k in range(1_000_000):
        s = samples[k % len(samples)]
        est.update_imu(type(s)(k / 400.0, s.gyro, s.accel, s.mag, s.source))
    assert orthonormality_error(est.rows) < 1e-9
    assert est.health()["renorm_max"] < 1e-9


def test_gain_change_takes_effect():
    """With kp_rp = ki_rp = 0 a wrong tilt stays; raising kp_rp then corrects it, without a jump."""
    est = DcmEstimator(kp_rp=0.0, ki_rp=0.0)
    est.update_imu(imu(0.0, euler_to_quat(0.0, 0.0, 0.0)))
    for s in static(D(30), 0.0, 0.0, rate=50, duration=10, t0=0.02):
        est.update_imu(s)
    assert abs(quat_to_euler(est.quaternion)[0]) < D(0.01)
    est.set_gain("kp_rp", 1.0)
    rolls = []
    for s in static(D(30), 0.0, 0.0, rate=50, duration=10, t0=10.02):
        est.update_imu(s)
        rolls.append(quat_to_euler(est.quaternion)[0])
    assert max(np.abs(np.diff(rolls))) < D(1.0)  # 1 rad/s·sin(30°)·20 ms = 0.57° per step at most
    assert abs(rolls[-1] - D(30)) < D(0.1)


def test_gps_acceleration_is_removed_from_the_specific_force():
    """Level vehicle accelerating north at 2 m/s² for 10 s: without GPS the accelerometer looks
    like 11.5° of pitch; with GPS dv/dt removed the estimate stays level."""

    def run(gps_gain):
        est = DcmEstimator(gps_gain=gps_gain)
        q = euler_to_quat(0.0, 0.0, 0.0)
        for k in range(1000):
            t = k / 100.0
            if k % 20 == 0:  # 5 Hz GPS
                v = np.array([2.0 * t, 0.0, 0.0])
                est.update_gps(GpsSample(t, 0.0, 0.0, 0.0, float(v[0]), 0.0, v, 3))
            est.update_imu(imu(t, q, a_ned=(2.0, 0.0, 0.0)))
        return abs(math.degrees(quat_to_euler(est.quaternion)[1]))

    assert run(0.0) > 5.0
    # The start-up tilt is the accelerating sample's 11.5°, corrected at kp_rp 0.2; the first GPS
    # dv/dt arrives after 0.2 s and enters the 1 s reference average gradually (0.28° with
    # accel_tau = 0, 0.57° with the default 1 s).
    assert run(1.0) < 1.0


def test_presets():
    seed = DcmEstimator("seed000").gains
    assert (seed["kp_rp"], seed["kp_yaw"], seed["ki_rp"], seed["ki_yaw"]) == (27.8, 41.7, 1.0, 1.5)
    ap = DcmEstimator("ardupilot").gains
    # AHRS_YAW_P doubled at rest; the turn-rate schedule halves it at 2.5 rad/s (docs/estimators/dcm.md)
    assert (ap["kp_rp"], ap["kp_yaw"], ap["ki_rp"], ap["ki_yaw"]) == (0.2, 0.4, 0.0087, 0.01)
    assert (ap["yaw_spin_half"], ap["accel_dev_gate"], ap["yaw_acc_cap"]) == (2.5, 7.0, 0.4)
    assert (seed["yaw_spin_half"], seed["accel_dev_gate"], seed["yaw_acc_cap"], seed["pick_dt"]) == (0.0,) * 4
    assert DcmEstimator.DEFAULT_PRESET == "ardupilot"


def hop_rms(**kw):
    c = compare_stream(read_samples(HOP), DcmEstimator(declination=HOP_DECLINATION, **kw))
    return c.summary()["references"]


@pytest.mark.slow
def test_sitl_hop_accuracy_vs_simstate():
    """Acceptance: RMS roll and pitch error vs SIMSTATE truth ≤ 2.5° (measured 0.29°/0.22°);
    the GPS acceleration compensation is what makes it, and `ardupilot` beats `seed000`."""
    refs = hop_rms()
    roll, pitch, yaw = refs["truth"]["session"]["rms"]
    assert roll < 1.0 and pitch < 1.0 and yaw < 2.0
    without_gps = hop_rms(gps_gain=0.0)["truth"]["session"]["rms"]
    assert without_gps[0] > 1.5 * roll and without_gps[1] > 1.5 * pitch
    seed = hop_rms(**DcmEstimator.PRESETS["seed000"])["truth"]["session"]["rms"]
    assert seed[0] > roll and seed[1] > pitch


def test_magnetic_disturbance_is_rejected_then_relearned():
    """Level and still, then the field grows 40% and turns 30° (a magnet nearby): the heading must
    not follow it; once the disturbed field has been steady for mag_relearn s of turning it becomes
    the reference and the yaw correction is used again."""
    from gcs.core.rotation import quat_from_rotvec, quat_to_matrix

    def run(**kw):
        est = DcmEstimator(mag_relearn=5.0, **kw)
        for s in static(0.0, 0.0, 0.0, rate=100, duration=2):
            est.update_imu(s)
        c, sn = math.cos(D(30)), math.sin(D(30))
        bad = 1.4 * np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]]) @ np.array([0.25, 0.0, 0.433])
        for s in static(0.0, 0.0, 0.0, rate=100, duration=10, t0=2.0):
            est.update_imu(type(s)(s.t, s.gyro, s.accel, bad, s.source))
        return est, abs(math.degrees(quat_to_euler(est.quaternion)[2]))

    est, yaw = run()
    assert yaw < 0.1 and est.health()["mag_disturbed"] and est.health()["yaw_source"] == "mag_rejected"
    assert run(**MAG_OFF)[1] > 10.0  # without rejection it follows the magnet
    # turning at 30 deg/s about down in the disturbed (but earth-fixed) field: relearned after 5 s
    c, sn = math.cos(D(30)), math.sin(D(30))
    bad = 1.4 * np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]]) @ np.array([0.25, 0.0, 0.433])
    for k in range(800):
        att = quat_from_rotvec(np.array([0.0, 0.0, D(30) * k / 100]))
        R = quat_to_matrix(att)
        s = imu(12.0 + k / 100, att, gyro=(0.0, 0.0, D(30)))
        est.update_imu(type(s)(s.t, s.gyro, s.accel, R.T @ bad, s.source))
    assert not est.health()["mag_disturbed"] and est.health()["yaw_source"] == "mag"


@pytest.mark.parametrize("trial", ["15_undisturbed_fast_translation", "30_disturbed_stationary_magnet"])
def test_broad_robustness_regression(trial):
    """Fast translation (linear acceleration, no GPS) and fast rotation near a magnet, at 47.6 Hz:
    before the earth-frame accel average, accel weight, roll-pitch-only spin gain and magnetic
    disturbance rejection these scored 22.9° and 21.0° total RMSE; now about 4.5° and 3.6°."""
    assert broad_rmse(DcmEstimator(), trial, 6) < 7.0
