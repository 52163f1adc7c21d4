"""Acceptance on the shared BROAD trials with the stress cases of bench/stress.py (the one place
that builds them): a magnet fixed to the sensor, a gyro bias step, accelerometer shocks.

Every case runs the whole trial and scores the whole rest after the switch (at its middle), at
47.6 Hz (every 6th sample, what RAW_IMU streaming gives) and some at the full 285.7 Hz too; until
2026-12-03 they ran only to 40 s after the switch, for CI time (whole trials take about 1.5× the
CPU). The figures of every case: `python -m bench.stress`."""

import math

import numpy as np
import pytest
from conftest import DATA

from bench.broad import load_trial, run_estimator, run_vqf
from bench.stress import BIAS_STEP, bias_step, floor_magnet, magnet, mid, score, shocks
from gcs.core.estimators import registry

BROAD = DATA / "broad"
TRIALS = sorted(p.stem for p in BROAD.glob("*.hdf5"))
NAMES = registry.names()
EVERY = 6


def switched(stem: str, every: int = EVERY):
    """The whole trial, and its middle (the switch time)."""
    trial = load_trial(BROAD / f"{stem}.hdf5", every)
    return trial, mid(trial)


def test_all_six_trials_are_there():
    assert len(TRIALS) == 6, f"BROAD trials missing in {BROAD}: {TRIALS}"


@pytest.mark.parametrize("every", [EVERY, 1])
@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("stem", TRIALS)
def test_magnet_fixed_to_the_sensor(stem, name, every):
    """A 100 µT body-fixed field (twice the earth's) from the middle of the trial on: the heading
    error over the whole rest of the trial stays below 5° RMS, at 47.6 and 285.7 Hz (before robust
    heading: 48° mean, 94° worst for ekf; VQF, which relearns it as a new earth field, 16° mean,
    59° worst). The last misses: dcm on trial 15 at 5.31° (40 s after the switch, 47.6 Hz), 2.50°
    since its yaw gain has a ceiling in acceleration (docs/estimators/dcm.md); kf there at 5.20°
    and 5.34°, 2.90° and 3.04° since its field heading has a noise floor in acceleration
    (`yaw_acc_r`, docs/estimators/kf.md)."""
    trial, t_on = switched(stem, every)
    stressed = magnet(trial, 100.0, t_on)
    err = score(stressed, run_estimator(name, stressed), t_on)
    assert err["heading"] < 5.0, err


@pytest.mark.parametrize("offset", [20.0, 50.0])
@pytest.mark.parametrize("name", NAMES)
def test_magnet_in_slow_translation(name, offset):
    """Trial 10 (slow translation) with a 20 or 50 µT body-fixed magnet: heading within 2× VQF's
    (VQF 1.0-1.3°: it rejects the field and coasts on its gyro, which beats this trial's field). It
    was 2.2-2.7× while ours went back to the field as soon as the offset was learned; they now
    coast on the gyro first (magnetic.py: 0.9-1.5× over the rest of the trial)."""
    trial, t_on = switched(next(s for s in TRIALS if s.startswith("10")))
    stressed = magnet(trial, offset, t_on)
    ours = score(stressed, run_estimator(name, stressed), t_on)["heading"]
    vqf = score(stressed, run_vqf(stressed), t_on)["heading"]
    assert ours < 2.0 * vqf, (ours, vqf)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("stem", [s for s in TRIALS if s.startswith(("02", "07"))])
def test_shocks_leave_no_lasting_error(stem, name):
    """Six 20 ms spikes of 8 to 16 g in the 20 s before the middle (a hard touch-down, taps): 10 s
    after the last one the estimate is within 2° of the same estimator's run without them."""
    trial, t_on = switched(stem)
    clean = run_estimator(name, trial)
    shocked = run_estimator(name, shocks(trial, t_on - 20.0, t_on))
    t = np.asarray(trial["t"])
    after = (t >= t_on + 10.0) & (t < t_on + 20.0)
    dot = np.abs(np.sum(clean[after] * shocked[after], axis=1))
    worst = math.degrees(2 * math.acos(min(1.0, float(dot.min()))))
    assert worst < 2.0


@pytest.mark.parametrize("every", [EVERY, 1])
@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("stem", TRIALS)
def test_gyro_bias_step(stem, name, every):
    """1°/s added to gyro x at the middle: the total error after the step stays within twice
    VQF's on the same samples (VQF estimates the bias too), at 47.6 Hz and at the full 285.7 Hz
    (kf, before it learned the bias: 2.2x and 2.7x on the full trials; dcm on trial 15 at 47.6 Hz
    2.03x until its yaw gain got a ceiling in acceleration, now 1.91x over the rest of the trial)."""
    trial, t_on = switched(stem, every)
    stressed = bias_step(trial, BIAS_STEP, t_on)
    ours = score(stressed, run_estimator(name, stressed), t_on)["total"]
    vqf = score(stressed, run_vqf(stressed), t_on)["total"]
    assert ours < 2.0 * max(vqf, 1.5), (ours, vqf)


@pytest.mark.parametrize("offset", [20.0, 100.0])
@pytest.mark.parametrize("name", NAMES)
def test_magnet_in_fast_rotation_at_full_rate(name, offset):
    """Trial 07 (fast rotation, up to 1450°/s) at the full 285.7 Hz with a body-fixed magnet from
    the middle: heading within 2× VQF's (VQF 1.1°). It was 2.0-2.8× while dcm and kf learned the
    gyro's bias only through their corrections (a 0.23°/s z bias left 2° of heading) and ekf
    trusted the field as much in a 1000°/s turn as at rest."""
    trial, t_on = switched(next(s for s in TRIALS if s.startswith("07")), every=1)
    stressed = magnet(trial, offset, t_on)
    ours = score(stressed, run_estimator(name, stressed), t_on)["heading"]
    vqf = score(stressed, run_vqf(stressed), t_on)["heading"]
    assert ours < 2.0 * vqf, (ours, vqf)


@pytest.mark.parametrize("name", NAMES)
def test_floor_magnet_is_not_hard_iron(name):
    """Trial 10 (slow translation) over a magnet lying on the floor (bench.stress's place-fixed
    dipole), whole trial at 47.6 Hz: heading within 2× VQF's. The sensor starts at rest over the
    magnet and then moves away; with little net rotation the changed field looked fixed to the
    sensor and was learned as a 15 µT hard-iron offset that kept the start's 50° heading error
    (2.3-2.8× VQF). An offset now has to swing first (magnetic.py, MAG_OFFSET_SWING)."""
    trial = load_trial(BROAD / f"{next(s for s in TRIALS if s.startswith('10'))}.hdf5", EVERY)
    stressed = floor_magnet(trial)
    ours = score(stressed, run_estimator(name, stressed))["heading"]
    vqf = score(stressed, run_vqf(stressed))["heading"]
    assert ours < 2.0 * vqf, (ours, vqf)


@pytest.mark.parametrize("every", [EVERY, 1])
@pytest.mark.parametrize("name", NAMES)
def test_floor_magnet_under_the_rest_place(name, every):
    """Trial 30 over the floor magnet, whole trial at 47.6 and 285.7 Hz: heading within 1.6× VQF's
    (reached: 1.22× and 1.48×, dcm; the target is 2×). The sensor
    rests over the magnet at the start and between movements, so the reference is the disturbed
    field and the clean one fails the heading check while moving; dcm went back to the disturbed
    heading in every rest (2.09× and 2.32× VQF; kf 2.10× at 285.7 Hz). After 20 s of fast turning
    with the field steadily off the heading, the heading is distrusted and the rest place's field
    is remembered as rejected (magnetic.py, MagneticHeading._new_heading)."""
    trial = load_trial(BROAD / f"{next(s for s in TRIALS if s.startswith('30'))}.hdf5", every)
    stressed = floor_magnet(trial)
    ours = score(stressed, run_estimator(name, stressed))["heading"]
    vqf = score(stressed, run_vqf(stressed))["heading"]
    assert ours < 1.6 * vqf, (ours, vqf)
