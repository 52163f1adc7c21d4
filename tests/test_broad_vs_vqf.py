"""Every estimator against VQF on every shared BROAD trial as recorded, at the full 285.7 Hz and
at every 6th sample (47.6 Hz, picked as RAW_IMU picks them): within 1.6× VQF's total RMSE on the
same samples (issue 10's target is 2×; measured worst 1.55×, kf on trial 15 at 47.6 Hz). dcm on
trial 15 at 47.6 Hz, 1.81× before its yaw gain got a ceiling in acceleration, is 1.09×.
The figures and the leave-one-out: `python -m bench.loo`, docs/benchmarks.md."""

import pytest
from conftest import DATA

from bench.broad import broad_errors, load_trial, run_estimator, run_vqf
from gcs.core.estimators import registry

TRIALS = sorted(p.stem for p in (DATA / "broad").glob("*.hdf5"))
BOUND = 1.6


def test_all_six_trials_are_there():
    assert len(TRIALS) == 6


@pytest.mark.parametrize("every", [1, 6])
@pytest.mark.parametrize("stem", TRIALS)
def test_close_to_vqf(stem, every):
    trial = load_trial(DATA / "broad" / f"{stem}.hdf5", every)
    vqf = broad_errors(run_vqf(trial), trial["opt_quat"], trial["movement"])["total"]
    for name in registry.names():
        ours = broad_errors(run_estimator(name, trial), trial["opt_quat"], trial["movement"])["total"]
        assert ours < BOUND * vqf, f"{name} on {stem} every {every}: {ours:.2f}° against VQF {vqf:.2f}°"
