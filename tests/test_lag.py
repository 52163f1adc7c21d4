"""The running lag (gcs.core.lag, kept as references arrive) gives the lag the full search over
the history gave (the search the Comparison ran per snapshot before issue 17, kept here as the
readable reference) on known delays, ahead and behind, with noise, and across a clock reset."""

import math

import numpy as np
import pytest

from gcs.core.comparison import Comparison
from gcs.core.rotation import euler_to_quat, wrap_pi_array
from gcs.core.samples import AttitudeSample

D = math.radians


def wave(t: float) -> tuple[float, float]:
    return D(20) * math.sin(2 * math.pi * 0.5 * t), D(8) * math.sin(2 * math.pi * 0.3 * t + 1.0)


def full_search(est: np.ndarray, ref: np.ndarray, lag_max=0.5, lag_step=0.01) -> float | None:
    """Every lag on the grid over every reference: the mean of roll² + pitch² errors."""
    steps = int(round(lag_max / lag_step))
    best, best_cost = None, math.inf
    for k in range(-steps, steps + 1):
        lag = k * lag_step
        ts = ref[:, 0] + lag
        inside = (ts >= est[0, 0]) & (ts <= est[-1, 0])
        if inside.sum() < 10:
            continue
        dr = wrap_pi_array(np.interp(ts[inside], est[:, 0], est[:, 1]) - ref[inside, 1])
        dp = np.interp(ts[inside], est[:, 0], est[:, 2]) - ref[inside, 2]
        cost = float(np.mean(dr * dr + dp * dp))
        if cost < best_cost:
            best, best_cost = lag, cost
    return best


def run(lag: float, duration: float, t0: float = 0.0, noise: float = 0.0, c: Comparison | None = None):
    """Estimator = the truth delayed by `lag` at 200 Hz, ATTITUDE at 50 Hz; returns the comparison
    and the last 30 s of both as arrays (t, roll, pitch)."""
    c = c or Comparison()
    rng = np.random.default_rng(1)
    est, ref = [], []
    for k in range(int(duration * 200)):
        t = t0 + k / 200
        if k % 4 == 0:
            roll, pitch = wave(t)
            c.add_reference(AttitudeSample(t, roll, pitch, 0.3, "onboard"))
            ref.append((t, roll, pitch))
        roll, pitch = wave(t - lag)
        roll, pitch = roll + noise * rng.standard_normal(), pitch + noise * rng.standard_normal()
        c.add_estimate(t, euler_to_quat(roll, pitch, 0.0))
        est.append((t, roll, pitch))
    est_a, ref_a = np.array(est), np.array(ref)
    last = est_a[-1, 0]
    return c, est_a[est_a[:, 0] >= last - 30.0], ref_a[ref_a[:, 0] >= last - 30.0]


@pytest.mark.parametrize("lag", [0.07, -0.03, 0.0, 0.31])
def test_known_delay_as_the_full_search(lag):
    c, est, ref = run(lag, 40.0)
    expected = full_search(est, ref)
    assert expected == pytest.approx(lag, abs=1e-9)
    assert c.lag() == pytest.approx(expected, abs=1e-9)


def test_noisy_delay_as_the_full_search():
    c, est, ref = run(0.12, 45.0, noise=D(0.5))
    assert c.lag() == pytest.approx(full_search(est, ref), abs=1e-9)
    assert c.lag() == pytest.approx(0.12, abs=0.011)


def test_clock_going_back_starts_the_lag_again():
    c, _, _ = run(0.2, 20.0, t0=100.0)
    assert c.lag() == pytest.approx(0.2, abs=1e-9)
    c, est, ref = run(-0.05, 20.0, c=c)  # rebooted: vehicle time from 0
    assert c.lag() == pytest.approx(full_search(est, ref), abs=1e-9)
    assert c.lag() == pytest.approx(-0.05, abs=1e-9)


def test_no_overlap_no_lag():
    c, _, _ = run(0.0, 0.1)
    assert c.lag() is None


def test_a_vehicle_at_rest_has_no_lag():
    """Level and still, the estimator noisy: every lag fits as well as any other, and the least
    is noise (it was often ±0.5 s, shown as a measurement)."""
    c = Comparison()
    rng = np.random.default_rng(2)
    for k in range(30 * 200):
        t = k / 200
        if k % 4 == 0:
            c.add_reference(AttitudeSample(t, D(0.3), D(-0.2), 0.3, "onboard"))
        roll, pitch = D(0.3) + D(0.02) * rng.standard_normal(), D(-0.2) + D(0.02) * rng.standard_normal()
        c.add_estimate(t, euler_to_quat(roll, pitch, 0.0))
    assert c.lag() is None


def test_a_lag_beyond_the_search_is_not_its_edge():
    """0.8 s late, searched within ±0.5 s: the least is at +0.5 s, which is not the lag."""
    c, est, ref = run(0.8, 40.0)
    assert full_search(est, ref) == pytest.approx(0.5, abs=1e-9)
    assert c.lag() is None
