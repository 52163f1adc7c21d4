"""`ekf` beyond the behaviour every estimator shares (tests/test_estimators_common.py): bias
estimation, GPS-velocity compensation of linear acceleration, heading-only magnetometer, gaps,
and acceptance on a SITL flight and on one BROAD trial."""

import json
import math
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from conftest import DATA, ROOT
from synthetic import MAG_NED, Z_UP, angle_between, imu, spinning, static

from bench.broad import broad_errors, load_trial, run_estimator, run_vqf
from gcs.core.estimation import compare_stream
from gcs.core.estimators.ekf import EkfEstimator
from gcs.core.rotation import (
    euler_to_quat,
    matrix_to_quat,
    quat_from_rotvec,
    quat_multiply,
    quat_to_euler,
    quat_to_matrix,
    wrap_pi,
)
from gcs.core.samples import G0, GpsSample
from gcs.logs.readers import read_samples

D = math.radians
BIAS = np.array([0.01, -0.02, 0.015])  # rad/s, body FRD


def in_frame(q, frame):
    """The attitude (sensor → NED) of a sensor mounted as `frame` on a body at attitude q."""
    return matrix_to_quat(quat_to_matrix(q) @ frame.T)


def tilt_error(q_est, q_true) -> float:
    """Angle (deg) between the estimated and the true "down", whatever the heading error."""
    cos = float(quat_to_matrix(q_est)[2] @ quat_to_matrix(q_true)[2])
    return math.degrees(math.acos(min(1.0, cos)))


@pytest.mark.parametrize("angle", [-60, -45, -30, 30, 45, 60])
def test_static_tilt_converges_and_bias_is_learned_at_rest(angle):
    """Initialised level, then still at a roll of `angle` (pitch half of it) with a biased gyro, in
    a z-up sensor frame: the zero-rate update finds the bias and the tilt converges."""
    truth = in_frame(euler_to_quat(D(angle), D(angle) / 2, D(20)), Z_UP)
    est = EkfEstimator()
    est.update_imu(imu(0.0, euler_to_quat(0.0, 0.0, 0.0), frame=Z_UP))
    for s in static(D(angle), D(angle) / 2, D(20), rate=25, duration=120, t0=0.04, gyro=BIAS, frame=Z_UP):
        est.update_imu(s)
    assert tilt_error(est.quaternion, truth) < 0.05  # at rest gravity alone fixes the tilt
    assert angle_between(est.quaternion, truth) < 1.0  # heading follows the magnetometer slowly
    assert np.allclose(est.b, Z_UP @ BIAS, atol=2e-4)
    assert est.health()["at_rest"] == 1


def test_gyro_bias_is_estimated_in_motion():
    """Turning all the time (never at rest): gravity and the magnetometer make the bias observable."""
    samples, truth = spinning(euler_to_quat(D(10), D(-5), 0.0), [0.3, -0.2, 0.5], rate=50, duration=60)
    est = EkfEstimator()
    for s in samples:
        est.update_imu(replace(s, gyro=s.gyro + BIAS))
    assert est.health()["at_rest"] == 0
    assert np.allclose(est.b, BIAS, atol=1e-3)
    assert angle_between(est.quaternion, truth[-1]) < 0.5


def test_fast_constant_rotation():
    samples, truth = spinning(
        in_frame(euler_to_quat(D(20), D(10), D(170)), Z_UP), [2.0, -1.0, 3.0], rate=200, duration=10, frame=Z_UP
    )
    est = EkfEstimator()
    worst = 0.0
    for s, q in zip(samples, truth):
        est.update_imu(s)
        worst = max(worst, angle_between(est.quaternion, in_frame(q, Z_UP)))
    assert worst < 0.5


def accelerating_run(with_gps: bool, rate: int = 50) -> float:
    """Still for 5 s, then 3 m/s² along a 30° course for 8 s (0 → 24 m/s), then cruising: the worst
    tilt error (deg). GPS velocity at 5 Hz when with_gps."""
    course = D(30)
    q = euler_to_quat(D(5), D(-5), course)
    direction = np.array([math.cos(course), math.sin(course), 0.0])
    est = EkfEstimator()
    worst = 0.0
    for k in range(25 * rate):
        t = k / rate
        speed = 3.0 * min(max(t - 5.0, 0.0), 8.0)
        if with_gps and k % (rate // 5) == 0:
            est.update_gps(GpsSample(t, math.nan, math.nan, math.nan, speed, course, speed * direction, 3, "test"))
        est.update_imu(imu(t, q, a_ned=(3.0 if 5.0 <= t < 13.0 else 0.0) * direction))
        worst = max(worst, tilt_error(est.quaternion, q))
    assert est.health()["gps_aided"] == int(with_gps)
    return worst


def test_gps_velocity_cancels_linear_acceleration():
    assert accelerating_run(with_gps=True) < 0.2
    assert accelerating_run(with_gps=False) > 5.0  # what the GPS removes


def test_magnetic_disturbance_does_not_tilt():
    """While turning, the field swings 40° about the vertical (|m| and dip unchanged, so nothing
    can detect it): the heading follows the wrong field, the tilt must not move at all."""
    samples, truth = spinning(euler_to_quat(D(20), D(-10), D(30)), [0.3, -0.2, 0.6], rate=50, duration=40)
    c, s = math.cos(D(40)), math.sin(D(40))
    bent = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ MAG_NED
    est = EkfEstimator()
    worst_tilt = 0.0
    for sample, q in zip(samples, truth):
        if sample.t >= 5.0:
            sample = replace(sample, mag=quat_to_matrix(q).T @ bent)
        est.update_imu(sample)
        worst_tilt = max(worst_tilt, tilt_error(est.quaternion, q))
    assert worst_tilt < 0.01
    assert angle_between(est.quaternion, truth[-1]) > 30.0  # the heading did follow the bent field


def test_magnet_fixed_to_the_sensor_is_rejected_then_learned_as_hard_iron():
    """A magnet fixed to the sensor changes |m| and the dip: the field is rejected (heading held by
    the gyro, tilt untouched) while the sensor is still; once it turns, the offset stays put in the
    sensor frame and is learned as hard iron, and the heading is corrected by m − b again."""
    roll, pitch, yaw = D(20), D(-10), D(30)
    q = euler_to_quat(roll, pitch, yaw)
    offset = np.array([0.0, 0.3, -0.2])
    est = EkfEstimator()
    for s in static(roll, pitch, yaw, duration=5):
        est.update_imu(s)
    for s in static(roll, pitch, yaw, duration=10, t0=5.0):
        est.update_imu(replace(s, mag=s.mag + offset))
        assert tilt_error(est.quaternion, q) < 0.01 and angle_between(est.quaternion, q) < 0.01
    assert est.health()["mag_rejected"] > 0 and est.health()["mag_disturbed"]
    turning, truth = spinning(q, [0.0, 0.0, D(30)], rate=100, duration=20)
    for s in turning:
        est.update_imu(replace(s, t=s.t + 15.0, mag=s.mag + offset))
    h = est.health()
    assert h["mag_offsets_learned"] == 1 and not h["mag_disturbed"]
    assert np.allclose(h["mag_offset"], offset, atol=0.01)
    assert angle_between(est.quaternion, truth[-1]) < 0.5


def test_gain_and_preset_change_mid_run_is_continuous():
    """A whole preset applied at once while turning: no jump beyond one step of motion."""
    samples, _ = spinning(euler_to_quat(D(10), D(5), D(30)), [0.2, 0.1, 0.5], rate=100, duration=4)
    est = EkfEstimator()
    out = []
    for s in samples[:200]:
        est.update_imu(s)
        out.append(est.quaternion)
    step = max(angle_between(a, b) for a, b in zip(out[100:], out[101:]))
    for name, value in EkfEstimator.PRESETS["telemetry"].items():
        est.set_gain(name, value)
    est.update_imu(samples[200])
    assert angle_between(out[-1], est.quaternion) < step + 0.01


def test_short_gap_is_bridged_long_gap_reinitialises():
    """A 0.3 s gap while turning is integrated (no re-init); a long one re-initialises, is
    reported, and GPS aiding has to start over."""
    samples, truth = spinning(euler_to_quat(D(10), D(5), D(30)), [0.0, 0.0, 0.5], rate=100, duration=6)
    est = EkfEstimator()
    est.update_gps(GpsSample(0.0, 0, 0, 0, 0.0, 0.0, np.zeros(3), 3, "test"))
    kept = [k for k in range(len(samples)) if not 300 <= k < 330]
    for k in kept:
        est.update_imu(samples[k])
        if k % 20 == 0:
            est.update_gps(GpsSample(samples[k].t, 0, 0, 0, 0.0, 0.0, np.zeros(3), 3, "test"))
    assert est.health()["reinit_count"] == 1  # only the first sample
    assert est.health()["gps_aided"] == 1
    assert angle_between(est.quaternion, truth[-1]) < 0.5
    est.update_imu(static(D(-15), D(5), 0.0, t0=20.0, duration=0.01)[0])
    h = est.health()
    assert "gap of" in h["last_reinit"] and h["reinit_count"] == 2
    assert h["gps_aided"] == 0
    assert tilt_error(est.quaternion, euler_to_quat(D(-15), D(5), 0.0)) < 0.01


def skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


class ReferenceStep:
    """The module docstring's equations transcribed plainly (full matrices, np.linalg.inv, textbook
    forms), applied to a copy of an estimator's state: what the optimised code must reproduce."""

    def __init__(self, est):
        self.g = dict(est.gains.values)
        self.q, self.v, self.b, self.P = np.array(est.q), np.array(est.v), np.array(est.b), est.P.copy()

    def predict(self, gyro, accel, dt, gyro_prev=None):
        """gyro_prev: the sample before, for picked samples (dt > pick_dt): the trapezoid plus the
        coning term (ω₀ × ω₁) dt²/12."""
        turn = (gyro - self.b) * dt
        if gyro_prev is not None and dt > self.g["pick_dt"]:
            w0, w1 = gyro_prev - self.b, gyro - self.b
            turn = 0.5 * (w0 + w1) * dt + np.cross(w0, w1) * dt * dt / 12.0
        self.q = quat_multiply(self.q, quat_from_rotvec(turn))
        self.q /= np.linalg.norm(self.q)
        R = quat_to_matrix(self.q)
        self.v = self.v + (R @ accel + G_NED) * dt
        F = np.eye(9)
        F[0:3, 6:9] = -R * dt
        F[3:6, 0:3] = -skew(R @ accel) * dt
        sa = self.g["acc_noise"] * (1.0 + ((np.linalg.norm(accel) - G0) / self.g["acc_gate"]) ** 2)
        Q = np.diag(np.repeat([self.g["gyro_noise"] ** 2, sa**2, self.g["bias_walk"] ** 2], 3) * dt)
        Q[2, 2] = self.g["heading_noise"] ** 2 * dt  # δθ in NED: its down axis is the heading
        self.P = F @ self.P @ F.T + Q

    def update(self, H, r, y):
        """Optimal gain: K = P Hᵀ (H P Hᵀ + r I)⁻¹, P ← (I − K H) P symmetrised, x ← x + K y."""
        K = self.P @ H.T @ np.linalg.inv(H @ self.P @ H.T + r * np.eye(len(H)))
        P = (np.eye(9) - K @ H) @ self.P
        self.P = 0.5 * (P + P.T)
        self.inject(K @ y)

    def heading(self, mag, gyro, dt):
        """Gain on δθ_D only, Joseph form (I − K H) P (I − K H)ᵀ + K r Kᵀ, H = e_3ᵀ (a field the
        shared disturbance test passed, with no hard-iron offset learned); r grows by the field's
        timing uncertainty in a turn, (|ω − b|·σ_t)² per 20 ms."""
        m_n = quat_to_matrix(self.q) @ mag
        m_h, m_norm = np.hypot(m_n[0], m_n[1]), np.linalg.norm(mag)
        turn = np.linalg.norm(gyro - self.b) * self.g["mag_time_sigma"]
        r = (self.g["mag_noise"] * m_norm / m_h) ** 2 / dt + turn**2 * max(1.0, 0.02 / dt)
        y = wrap_pi(self.g["declination"] - np.arctan2(m_n[1], m_n[0]))
        H = np.eye(9)[2:3]
        K = np.zeros((9, 1))
        K[2, 0] = self.P[2, 2] / (self.P[2, 2] + r)
        I_KH = np.eye(9) - K @ H
        self.P = I_KH @ self.P @ I_KH.T + r * K @ K.T
        self.inject(K[:, 0] * y)

    def inject(self, dx):
        self.q = quat_multiply(quat_from_rotvec(dx[0:3]), self.q)
        self.q /= np.linalg.norm(self.q)
        self.v, self.b = self.v + dx[3:6], self.b + dx[6:9]

    def assert_matches(self, est):
        for ours, ref in ((est.q, self.q), (est.v, self.v), (est.b, self.b), (est.P, self.P)):
            assert np.allclose(ours, ref, rtol=0.0, atol=1e-12), (ours, ref)


G_NED = np.array([0.0, 0.0, G0])
V_SEL = np.eye(9)[3:6]  # H of a velocity measurement


def test_every_step_matches_a_plain_transcription_of_the_equations():
    """Still (zero-rate and gravity updates), then turning and accelerating, with GPS from 8 s
    (aided: down-velocity prior only, GPS updates) and still again with GPS (zero-rate only).
    Each IMU and GPS step, from the estimator's own state, equals ReferenceStep to 1e-12."""
    q0 = euler_to_quat(D(20), D(-10), D(30))
    turning, truth = spinning(q0, [0.3, -0.2, 0.5], rate=50, duration=8, a_ned=(0.5, -0.3, 0.2))
    samples = static(D(20), D(-10), D(30), rate=50, duration=4, gyro=BIAS)
    samples += [replace(s, t=s.t + 4.0, gyro=s.gyro + BIAS) for s in turning]
    samples += static(*quat_to_euler(truth[-1]), rate=50, duration=4, t0=12.0, gyro=BIAS)
    est = EkfEstimator()
    est.update_imu(samples[0])
    paths = {"rest, unaided": 0, "rest, aided": 0, "moving, unaided": 0, "moving, aided": 0, "gps": 0, "heading": 0}
    for k, sample in enumerate(samples[1:], 1):
        ref = ReferenceStep(est)
        rejected = est.stats["mag_rejected"]
        est.update_imu(sample)
        gyro, accel, dt = sample.gyro, sample.accel, sample.t - samples[k - 1].t
        ref.predict(gyro, accel, dt, samples[k - 1].gyro if k > 1 else None)
        aided, at_rest = est.stats["gps_aided"], est.stats["at_rest"]
        if at_rest:
            ref.update(np.eye(9)[6:9], est.gains["rest_noise"] ** 2 / dt, gyro - ref.b)
            if not aided:
                H = np.hstack([skew(-G_NED), np.zeros((3, 6))])
                ref.update(H, est.gains["rest_acc_noise"] ** 2 / dt, quat_to_matrix(ref.q) @ accel + G_NED)
        rows = [2] if aided else [0, 1, 2]
        ref.update(V_SEL[rows], est.gains["vel_noise"] ** 2 / dt, -ref.v[rows])
        assert est.health()["mag_offset"] == (0.0, 0.0, 0.0)
        if est.stats["mag_rejected"] == rejected:
            ref.heading(sample.mag, sample.gyro, dt)
            paths["heading"] += 1
        ref.assert_matches(est)
        paths[f"{'rest' if at_rest else 'moving'}, {'aided' if aided else 'unaided'}"] += 1
        if sample.t >= 8.0 and k % 10 == 0:  # 5 Hz GPS: the first fix only starts the velocity
            vel = np.array([est.v[0] + 0.3, est.v[1] - 0.2, 0.0])
            ref = ReferenceStep(est)
            est.update_gps(GpsSample(sample.t, 0, 0, 0, 0.0, 0.0, vel, 3, "test"))
            if aided:
                ref.update(V_SEL[:2], est.gains["gps_noise"] ** 2, vel[:2] - ref.v[:2])
                ref.assert_matches(est)
                paths["gps"] += 1
    assert min(paths.values()) > 20, paths
    assert paths["heading"] > 0.9 * len(samples), paths


@pytest.mark.slow
def test_sitl_hop_roll_pitch_against_simstate(logs_dir):
    """ArduCopter SITL, RAW_IMU at 25 Hz with ±15° roll and ±10° pitch steps: GPS velocity removes
    the manoeuvre accelerations; RMS roll and pitch error against SIMSTATE truth ≤ 1.5°."""
    est = EkfEstimator()
    summary = compare_stream(read_samples(str(logs_dir / "arducopter-sitl-hop.tlog")), est).summary()
    truth = summary["references"]["truth"]["session"]
    roll_rms, pitch_rms, _ = truth["rms"]
    assert truth["n"] > 2000
    assert roll_rms <= 1.5 and pitch_rms <= 1.5, truth
    assert est.health()["gps_aided"] == 1


@pytest.mark.slow
def test_broad_fast_translation_decimated_regression(tmp_path):
    """BROAD's fast-translation trial at 47.6 Hz through `gcs estimate` and the benchmark's own
    scoring: ekf scored 1.28° total (VQF 2.44°) when tuned with its own graded magnetometer noise,
    2.61° (0.78° inclination) with the shared disturbance test; fail on a clear regression."""
    if not (DATA / "broad").is_dir():
        pytest.fail(f"BROAD data missing: {DATA / 'broad'}")
    out = tmp_path / "rows.json"
    cmd = [
        sys.executable,
        "-m",
        "bench.broad",
        "--trials",
        "15_undisturbed_fast_translation",
        "--every",
        "6",
        "--estimators",
        "ekf",
        "--json",
        str(out),
    ]
    subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True, timeout=120)
    row = next(r for r in json.loads(out.read_text()) if r["estimator"] == "ekf" and not r["trial"].startswith("mean"))
    assert row["total"] < 3.0 and row["inclination"] < 1.5, row


@pytest.mark.parametrize("stem", ["07_undisturbed_fast_rotation_B", "30_disturbed_stationary_magnet_C"])
def test_picked_samples_turn_with_the_coning_term(stem):
    """BROAD's fast rotations at every 6th sample (47.6 Hz, picked as RAW_IMU picks them), 7-10°
    per step: with the trapezoid + coning turn (dt > pick_dt) the default ekf is ahead of VQF
    (measured 2.90° / 2.63° total against VQF's 5.41° / 3.91°); the rectangle a log's interval
    means get (pick_dt above the step) drifts in heading (4.14° / 3.71°)."""
    trial = load_trial(DATA / "broad" / f"{stem}.hdf5", 6)
    total = {
        name: broad_errors(q, trial["opt_quat"], trial["movement"])["total"]
        for name, q in (
            ("picked", run_estimator("ekf", trial)),
            ("rectangle", run_estimator("ekf", trial, pick_dt=1.0)),
            ("vqf", run_vqf(trial)),
        )
    }
    assert total["picked"] < total["vqf"] and total["picked"] < total["rectangle"] - 0.5, total
