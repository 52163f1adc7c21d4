"""The comparison's running statistics (window and session RMS and max, IMU rate) equal the same
figures computed from scratch over the samples they cover, over a session long enough for the
window to slide many times and the running sums to be re-summed."""

from __future__ import annotations

import math

import numpy as np

from gcs.core.comparison import RESUM_EVERY, Comparison
from gcs.core.rotation import euler_quat
from gcs.core.samples import AttitudeSample


def test_running_statistics_equal_a_recomputation():
    rng = np.random.default_rng(7)
    c = Comparison(window=2.0)
    refs: list[tuple[float, float, float, float]] = []  # (t, roll, pitch, yaw) of each onboard reference
    est: dict[float, tuple[float, float, float]] = {}
    t_imu = np.cumsum(rng.uniform(0.004, 0.016, 20_000))  # ~100 Hz with jitter, 200 s
    angles = np.cumsum(rng.normal(0.0, 0.01, (len(t_imu), 3)), axis=0)
    for k, t in enumerate(t_imu.tolist()):
        r, p, y = angles[k].tolist()
        c.add_estimate(t, np.array(euler_quat(r, p, y)))
        est[t] = (r, p, y)
        if k % 2 == 1:  # a reference at the same time as this estimate, off by a known error
            e = rng.normal(0.0, 0.05, 3) * (10.0 if k % 997 == 1 else 1.0)
            ref = (t, r - e[0], p - e[1], y - e[2])
            refs.append(ref)
            c.add_reference(AttitudeSample(*ref, source="onboard"))
    assert len(refs) > 2 * RESUM_EVERY  # the window's sums have been re-summed
    summary = c.summary()["references"]["onboard"]
    t_end = refs[-1][0]
    wrap = math.remainder
    errors = np.array([[math.degrees(wrap(a - b, math.tau)) for a, b in zip(est[t], ref)] for t, *ref in refs])
    in_window = np.array([t >= t_end - 2.0 for t, *_ in refs])
    window = errors[in_window]
    assert summary["n"] == len(refs) and summary["window"]["n"] == len(window)
    assert np.allclose(summary["window"]["rms"], np.sqrt(np.mean(window**2, axis=0)), rtol=1e-9, atol=1e-12)
    assert np.allclose(summary["window"]["max"], np.abs(window).max(axis=0), rtol=1e-9, atol=1e-12)
    assert np.allclose(summary["session"]["rms"], np.sqrt(np.mean(errors**2, axis=0)), rtol=1e-9)
    assert np.allclose(summary["session"]["max"], np.abs(errors).max(axis=0), rtol=1e-9)
    recent = t_imu[t_imu >= t_imu[-1] - 2.0]
    assert math.isclose(c.imu_rate(), (len(recent) - 1) / (recent[-1] - recent[0]), rel_tol=1e-12)


def test_the_window_max_falls_when_a_peak_leaves_it():
    c = Comparison(window=1.0)
    for k in range(400):
        t = k * 0.01
        c.add_estimate(t, np.array([1.0, 0.0, 0.0, 0.0]))
        roll = math.radians(10.0) if k == 50 else math.radians(1.0)
        c.add_reference(AttitudeSample(t, -roll, 0.0, 0.0, source="onboard"))
        peak = c.summary()["references"]["onboard"]["window"]["max"][0]
        assert math.isclose(peak, 10.0 if 50 <= k <= 150 else 1.0, rel_tol=1e-9), (k, peak)
