"""compare.py against synthetic references with known offset and lag, live = offline, rate flag."""

import math
from pathlib import Path

import numpy as np
import pytest

from gcs.core.comparison import Comparison, errors_against, errors_at
from gcs.core.estimation import compare_stream
from gcs.core.estimators import registry
from gcs.core.rotation import euler_to_quat
from gcs.core.samples import AttitudeSample
from gcs.logs.readers import read_samples
from gcs.mavlink.sampling import UNREADY

LOGS = Path(__file__).resolve().parents[2] / "shared/data/logs"
D = math.radians


def roll_wave(t):
    return D(20) * math.sin(2 * math.pi * 0.5 * t)


def feed(c, duration=30.0, rate=100.0, ref_rate=25.0, offset=(0.0, 0.0, 0.0), lag=0.0, source="onboard"):
    """Estimator output = the truth delayed by `lag` plus `offset`; references in arrival order."""
    n_ref = int(rate / ref_rate)
    for k in range(int(duration * rate)):
        t = k / rate
        q = euler_to_quat(roll_wave(t - lag) + offset[0], D(5) + offset[1], D(179) + offset[2])
        if k % n_ref == 0:  # the reference arrives before the IMU sample of the same time
            c.add_reference(AttitudeSample(t, roll_wave(t), D(5), D(179), source))
        c.add_estimate(t, q)


def test_known_offset():
    c = Comparison()
    feed(c, offset=(D(2), D(-1), D(3)))  # yaw 179° + 3° wraps to −178°
    s = c.summary()["references"]["onboard"]
    assert s["session"]["rms"] == pytest.approx([2.0, 1.0, 3.0], abs=1e-6)
    assert s["session"]["max"] == pytest.approx([2.0, 1.0, 3.0], abs=1e-6)
    assert s["window"]["n"] == pytest.approx(10 * 25, abs=1)


def test_known_lag_is_found():
    c = Comparison()
    feed(c, lag=0.12)
    assert c.summary()["lag"] == pytest.approx(0.12, abs=0.011)
    c = Comparison()
    feed(c, lag=0.0)
    assert c.summary()["lag"] == pytest.approx(0.0, abs=0.011)


def test_window_forgets_and_session_remembers():
    c = Comparison(window=10.0)
    feed(c, duration=20.0, offset=(D(4), 0.0, 0.0))
    for k in range(2000, 4000):  # then 20 s with no error
        t = k / 100.0
        if k % 4 == 0:
            c.add_reference(AttitudeSample(t, roll_wave(t), D(5), D(179), "onboard"))
        c.add_estimate(t, euler_to_quat(roll_wave(t), D(5), D(179)))
    s = c.summary()["references"]["onboard"]
    assert s["window"]["rms"][0] == pytest.approx(0.0, abs=1e-6)
    assert s["session"]["rms"][0] == pytest.approx(4.0 / math.sqrt(2), rel=0.01)
    assert s["session"]["max"][0] == pytest.approx(4.0, abs=1e-6)


def test_references_before_any_estimate_are_dropped_not_crashing():
    c = Comparison()
    c.add_reference(AttitudeSample(0.0, 0.0, 0.0, 0.0, "truth"))
    c.add_estimate(1.0, euler_to_quat(0, 0, 0))
    assert c.summary()["dropped"] == 1


def test_reliability_flag():
    c = Comparison()
    feed(c, duration=5.0, rate=100.0)
    assert c.summary()["reliable"] is True
    c = Comparison()
    feed(c, duration=5.0, rate=24.8, ref_rate=24.8)
    s = c.summary()
    assert s["reliable"] is False and s["reason"].startswith("raw IMU at 24.8 Hz, below the 50 Hz needed")


@pytest.mark.parametrize("rate", [50.0, 49.0])
def test_the_requested_rate_is_reliable(rate):
    """50 Hz requested and 50 Hz measured (or 49 Hz: a lost message and clock rounding) is reliable."""
    c = Comparison()
    feed(c, duration=12.0, rate=rate, ref_rate=rate / 2)
    s = c.summary()
    assert s["reliable"] is True and s["reason"] == ""
    c = Comparison()
    feed(c, duration=12.0, rate=40.0, ref_rate=20.0)  # one ArduPilot group rate step below: not reliable
    assert c.summary()["reliable"] is False


def roll_near_180(t):
    return D(179.5) * (1 if int(t * 4) % 2 == 0 else -1)  # flips between +179.5° and −179.5°


def test_roll_near_180_scores_the_same_everywhere():
    """Upside down, roll flipping across ±180°: the estimator equals the reference, so every error
    is ≈0 in the live Comparison, in what-if / report's whole-run errors_against, and in errors_at."""
    times = [k / 100.0 for k in range(1000)]
    euler = [(roll_near_180(t), D(3), D(-179.9) if k % 2 else D(179.9)) for k, t in enumerate(times)]
    live = Comparison()
    refs = []
    for k, t in enumerate(times):
        if k % 4 == 0:
            live.add_reference(AttitudeSample(t, *euler[k], "truth"))
            refs.append((t, *euler[k]))
        live.add_estimate(t, euler_to_quat(*euler[k]))
    live_rms = live.summary()["references"]["truth"]["session"]["rms"]
    series = np.array([(t, *e) for t, e in zip(times, euler)])
    whole = errors_against(series, np.array(refs))
    quats = np.array([euler_to_quat(*e) for e in euler])
    at = errors_at(np.array(times), quats, np.array(refs))
    assert live_rms == pytest.approx([0.0, 0.0, 0.0], abs=1e-6)
    for err in (whole, at):
        assert len(err) == len(refs)
        assert np.sqrt(np.mean(err[:, 1:] ** 2, axis=0)) == pytest.approx([0.0, 0.0, 0.0], abs=1e-6)
    # between the flips the slerped estimator stays upside down: no 180° error at a reference time
    # that falls between an output at +179.5° and one at −179.5°
    mid = errors_at(np.array([0.0, 1.0]), quats[[0, 25]], np.array([[0.5, D(180.0), D(3), D(179.9)]]))
    assert np.abs(mid[0, 1:]) == pytest.approx([0.0, 0.0, 0.0], abs=0.2)


def test_vtol_at_4_hz_is_unreliable():
    est = registry.create("dcm")
    s = compare_stream(read_samples(str(LOGS / "arduplane-sitl-vtol.tlog")), est).summary()
    assert s["reliable"] is False
    assert "raw IMU at 4.2 Hz, below the 50 Hz needed" in s["reason"]


def test_live_numbers_equal_offline_recomputation():
    """Live: summaries read while feeding; offline: a fresh run over the recorded stream."""
    samples = list(read_samples(str(LOGS / "arducopter-sitl-hop.tlog")))
    live = Comparison()
    est = registry.create("dcm")
    for k in range(0, len(samples), 500):
        compare_stream(samples[k : k + 500], est, live)
        live.summary()
    offline = compare_stream(samples, registry.create("dcm")).summary()
    assert live.summary() == offline
    # the first 0.3 s of ATTITUDE came before the copter's EKF_STATUS_REPORT said its attitude good
    assert set(offline["references"]) == {"onboard", UNREADY, "ahrs2", "truth"}
    assert offline["references"][UNREADY]["n"] == 7
    assert offline["lag"] is not None and abs(offline["lag"]) <= 0.1
