"""The running lag (gcs.core.lag, kept as references arrive) gives the lag a full search over the
history gives (every lag over every reference, as the Comparison searched per snapshot before
issue 17, kept here as the readable reference) on known delays, ahead and behind, with noise,
with a steady or drifting offset, and across a clock reset."""

import math
from collections.abc import Callable

import numpy as np
import pytest

from gcs.core.comparison import LAG_POINTS, Comparison
from gcs.core.lag import CHANGE_OVER
from gcs.core.rotation import euler_to_quat, wrap_pi_array
from gcs.core.samples import AttitudeSample

D = math.radians


def wave(t: float) -> tuple[float, float]:
    return D(20) * math.sin(2 * math.pi * 0.5 * t), D(8) * math.sin(2 * math.pi * 0.3 * t + 1.0)


def turning(t: float) -> tuple[float, float]:
    """A slow roll into a turn (1°/s) with small corrections: the attitude changes little within
    a second but a lot over the history, as a plane's in a turn."""
    return D(1.0) * t + D(1.0) * math.sin(2 * math.pi * 0.5 * t), D(1.0) * math.sin(2 * math.pi * 0.3 * t + 1.0)


def decimated(ref: np.ndarray, spacing: float = 30.0 / LAG_POINTS) -> np.ndarray:
    """The references the running lag keeps: one at least `spacing` after the last kept."""
    kept, last = [], -math.inf
    for row in ref:
        if row[0] >= last + spacing:
            kept.append(row)
            last = row[0]
    return np.array(kept)


def full_search(est: np.ndarray, ref: np.ndarray, lag_max=0.5, lag_step=0.01, history=30.0) -> float | None:
    """Every lag on the grid over every reference kept (`decimated`) of the last `history` s: the
    mean of the squared change of the roll and pitch errors since the reference kept CHANGE_OVER
    before (the newest at least that old, at most twice)."""
    ref = decimated(ref)
    pairs = []
    for i, t in enumerate(ref[:, 0]):
        older = np.flatnonzero(ref[:i, 0] <= t - CHANGE_OVER)
        if t >= ref[-1, 0] - history and len(older) and ref[older[-1], 0] >= t - 2 * CHANGE_OVER:
            pairs.append((i, older[-1]))
    now, before = np.array(pairs).T
    steps = int(round(lag_max / lag_step))
    best, best_cost = None, math.inf
    for k in range(-steps, steps + 1):
        lag = k * lag_step
        ts = ref[:, 0] + lag
        inside = (ts >= est[0, 0]) & (ts <= est[-1, 0])
        both = inside[now] & inside[before]
        if both.sum() < 10:
            continue
        dr = wrap_pi_array(np.interp(ts, est[:, 0], est[:, 1]) - ref[:, 1])
        dp = np.interp(ts, est[:, 0], est[:, 2]) - ref[:, 2]
        change_r, change_p = (dr[now] - dr[before])[both], (dp[now] - dp[before])[both]
        cost = float(np.mean(change_r**2 + change_p**2))
        if cost < best_cost:
            best, best_cost = lag, cost
    return best


def run(
    lag: float, duration: float, t0: float = 0.0, noise: float = 0.0, c: Comparison | None = None,
    offset: Callable[[float], float] = lambda t: 0.0, motion: Callable[[float], tuple[float, float]] = wave,
):  # fmt: skip
    """Estimator = the truth (`motion`) delayed by `lag` plus `offset(t)` (rad, on roll and pitch)
    at 200 Hz, ATTITUDE at 50 Hz; returns the comparison and both as arrays (t, roll, pitch)."""
    c = c or Comparison()
    rng = np.random.default_rng(1)
    est, ref = [], []
    for k in range(int(duration * 200)):
        t = t0 + k / 200
        if k % 4 == 0:
            roll, pitch = motion(t)
            c.add_reference(AttitudeSample(t, roll, pitch, 0.3, "onboard"))
            ref.append((t, roll, pitch))
        roll, pitch = motion(t - lag)
        roll, pitch = (
            roll + offset(t) + noise * rng.standard_normal(),
            pitch + offset(t) + noise * rng.standard_normal(),
        )
        c.add_estimate(t, euler_to_quat(roll, pitch, 0.0))
        est.append((t, roll, pitch))
    return c, np.array(est), np.array(ref)


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


@pytest.mark.parametrize(
    "offset", [lambda t: D(3.0), lambda t: D(0.1) * t], ids=["steady 3 deg", "drifting 0.1 deg per s"]
)
def test_an_offset_in_a_turn_is_not_a_lag(offset):
    """0.07 s late in a slow turn, and off by a steady 3° (dcm's roll in a turn, read off the
    centripetal acceleration) or by an offset growing 0.1°/s (dcm's as the turn goes on): the lag
    found is the true one. The mean squared error minimised before traded the offset for a slope
    of the attitude: a lag of -0.4 s or beyond the search."""
    c, est, ref = run(0.07, 40.0, offset=offset, motion=turning)
    assert c.lag() == pytest.approx(0.07, abs=1e-9)
    assert full_search(est, ref) == pytest.approx(0.07, abs=1e-9)


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
