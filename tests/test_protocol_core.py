"""The protocol's pure parts: the file format and its errors, hold detection, and each metric on
series whose answers are known by construction."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gcs.core.protocol import (
    ACCEL_MAG,
    HoldDetector,
    Protocol,
    ProtocolError,
    Step,
    StepWindow,
    accel_mag_series,
    parse_protocol,
    protocol_tables,
    step_metrics,
)
from gcs.sessions.protocol import available_protocols, load_protocol
from gcs.sim.motion import BenchScript, euler_matrix


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("name = 'x'", "at least one [[steps]]"),
        ("[[steps]]\naxis = 'yaw'\ntarget_deg = 30\nhold_s = 1", "tolerance_deg must be a number"),
        ("[[steps]]\naxis = 'heave'\ntarget_deg = 3\nhold_s = 1\ntolerance_deg = 1", "axis must be one of"),
        ("[[steps]]\naxis = 'roll'\ntarget_deg = 0\nhold_s = 1\ntolerance_deg = 1", "target_deg 0"),
        ("[[steps]]\naxis = 'roll'\ntarget_deg = 5\nhold_s = -1\ntolerance_deg = 1", "hold_s must be positive"),
        ("[[steps]]\naxis = 'roll'\ntarget = 5", "unknown field 'target'"),
        ("level_deg = [0, 0]\n[[steps]]\naxis = 'roll'\ntarget_deg = 5\nhold_s = 1\ntolerance_deg = 1", "level_deg"),
        ("[[steps]\n", "not valid TOML"),
    ],
)
def test_a_bad_protocol_file_is_refused_naming_the_field(text, message):
    with pytest.raises(ProtocolError, match=message.replace("[", r"\[")):
        parse_protocol(text, "bad")


def test_unknown_protocol_names_the_shipped_ones(tmp_path):
    with pytest.raises(ProtocolError, match="seed000-bench"):
        load_protocol(str(tmp_path / "missing.toml"))


def test_shipped_bench_protocol_is_what_the_simulator_does():
    assert {"seed000-bench", "seed000-circuit"} <= set(available_protocols())
    bench = load_protocol("seed000-bench")
    script = BenchScript()
    expected = [("roll", d) for d in script.ROLL_TARGETS_DEG]
    expected += [("pitch", d) for d in script.PITCH_TARGETS_DEG] + [("yaw", d) for d in script.YAW_TARGETS_DEG]
    assert [(s.axis, s.target_deg) for s in bench.steps] == expected
    assert all(s.hold_s < 5.0 for s in bench.steps)  # the script holds each angle for 5 s
    assert bench.last_samples == 22


def test_hold_needs_the_whole_time_inside_the_tolerance():
    detector = HoldDetector(Step("pitch", 30.0, hold_s=1.0, tolerance_deg=2.0))
    angles = {0.0: 25.0, 0.5: 29.0, 1.0: 33.0, 1.2: 31.0, 1.6: 30.2, 2.0: 30.5, 2.1: 29.0, 2.2: 30.0}
    results = {t: detector.feed(t, (0.0, math.radians(a), 0.0)) for t, a in angles.items()}
    assert results[2.0] is None  # 0.8 s since it came back inside at 1.2 s
    assert results[2.2] == (1.2, 2.2)
    gappy = HoldDetector(Step("pitch", 30.0, hold_s=1.0, tolerance_deg=2.0))
    seen = [gappy.feed(t, (0.0, math.radians(30.0), 0.0)) for t in (0.0, 0.3, 3.0, 3.4, 3.8, 4.0)]
    assert seen == [None, None, None, None, None, (3.0, 4.0)]  # not seen between 0.3 and 3.0 s


def _ramp_and_hold(target: float, offset: float, bump: float) -> np.ndarray:
    """Roll ramps linearly from 0 to target over 2 s (from t = 1 s), then holds at target + offset
    for 3 s at 100 Hz; pitch has a triangular bump of `bump` degrees mid-ramp."""
    t = np.arange(0.0, 6.0 + 1e-9, 0.01)
    roll = np.clip((t - 1.0) / 2.0, 0.0, 1.0) * target
    roll = np.where(t >= 3.0, target + offset, roll)
    pitch = bump * np.clip(1.0 - np.abs(t - 2.0) / 0.5, 0.0, None)
    return np.column_stack([t, np.radians(roll), np.radians(pitch), np.zeros_like(t)])


def test_step_metrics_on_a_known_step():
    protocol = Protocol("p", (Step("roll", -40.0, 3.0, 2.0),), settle_band_pct=5.0)
    series = _ramp_and_hold(-40.0, offset=0.4, bump=0.7)
    m = step_metrics(protocol, StepWindow(0, 1, 0.0, 3.0, 6.0), "s", series)
    assert m is not None
    assert m.n_hold == 301
    assert m.mre_last_pct == pytest.approx(100 * 0.4 / 40)  # seed 000: |x - target| / |target|
    assert m.abs_err_last_deg == pytest.approx(0.4)
    assert m.mse_roll == pytest.approx(0.16) and m.mse_pitch == pytest.approx(0.0) and m.mse_yaw == 0.0
    assert m.rise_s == pytest.approx(1.6, abs=0.011)  # 10 % at t = 1.2, 90 % at t = 2.8
    # inside ±2° (5 % of 40°) of the target from 95 % of the ramp, t = 2.9 (the hold's +0.4 stays in)
    assert m.settling_s == pytest.approx(2.9 - 1.2, abs=0.011)
    assert m.cross_deg == pytest.approx(0.7, abs=0.01)


def test_accel_mag_angles_recover_a_known_attitude():
    roll, pitch, yaw = math.radians(-35.0), math.radians(20.0), math.radians(50.0)
    R = euler_matrix(roll, pitch, yaw)  # body → NED
    f = R.T @ np.array([0.0, 0.0, -9.80665])  # a still accelerometer
    m = R.T @ np.array([0.21, 0.0, 0.43])  # a field pointing to magnetic north, dipping down
    imu = np.array([[1.0, 0.0, 0.0, 0.0, *f, *m], [2.0, 0.0, 0.0, 0.0, *f, math.nan, math.nan, math.nan]])
    out = accel_mag_series(imu, declination=math.radians(4.0))
    np.testing.assert_allclose(out[0], [1.0, roll, pitch, yaw + math.radians(4.0)], atol=1e-12)
    assert math.isnan(out[1, 3]) and out[1, 1] == pytest.approx(roll)


def test_tables_keep_the_last_attempt_and_score_the_reduction_against_accel_mag():
    step = Step("roll", -40.0, 3.0, 2.0)
    protocol = Protocol("p", (step,))
    good, raw = _ramp_and_hold(-40.0, 0.5, 0.0), _ramp_and_hold(-40.0, 1.0, 0.0)
    first = StepWindow(0, 1, 0.0, 0.0, 0.5)  # nothing held there: replaced by the repeat
    tables = protocol_tables(protocol, [first, StepWindow(0, 2, 0.0, 3.0, 6.0)], {"est": good, ACCEL_MAG: raw})
    assert [w.attempt for w in tables.windows] == [2]
    est = next(r for r in tables.mse if r.source == "est")
    assert est.mse_roll == pytest.approx(0.25)
    assert est.reduction_roll_pct == pytest.approx(75.0)  # 1 - 0.25 / 1.0
    (mean,) = [a for a in tables.axis_means if a.source == "est"]
    assert mean.mre_last_pct == pytest.approx(100 * 0.5 / 40)
