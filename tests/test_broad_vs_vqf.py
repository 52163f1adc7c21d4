"""Every estimator against VQF on every shared BROAD trial as recorded, at the full 285.7 Hz and
at every 6th sample (47.6 Hz, picked as RAW_IMU picks them): within 1.75× VQF's total RMSE on the
same samples (issue 10's target is 2×), but one stated shortfall: dcm on trial 15 at 47.6 Hz,
1.81× since dcm learns the gyro's bias at rest (1.54× before, when its heading lag from a
mis-learned bias cancelled part of the field's 2-6° error in that trial's volume).
The figures and the leave-one-out: `python -m bench.loo`, docs/benchmarks.md."""

import pytest
from conftest import DATA

from bench.broad import broad_errors, load_trial, run_estimator, run_vqf
from gcs.core.estimators import registry

TRIALS = sorted(p.stem for p in (DATA / "broad").glob("*.hdf5"))
BOUND = 1.75
#: (estimator, trial, every) → its own bound: a known shortfall held to what was measured.
SHORTFALLS = {("dcm", "15", 6): 1.85}


def test_all_six_trials_are_there():
    assert len(TRIALS) == 6


@pytest.mark.parametrize("every", [1, 6])
@pytest.mark.parametrize("stem", TRIALS)
def test_close_to_vqf(stem, every):
    trial = load_trial(DATA / "broad" / f"{stem}.hdf5", every)
    vqf = broad_errors(run_vqf(trial), trial["opt_quat"], trial["movement"])["total"]
    for name in registry.names():
        ours = broad_errors(run_estimator(name, trial), trial["opt_quat"], trial["movement"])["total"]
        bound = SHORTFALLS.get((name, stem[:2], every), BOUND)
        assert ours < bound * vqf, f"{name} on {stem} every {every}: {ours:.2f}° against VQF {vqf:.2f}°"
