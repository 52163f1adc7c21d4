"""Bad samples never stop estimation: inf, NaN and values beyond any sensor are refused and
counted, the estimators carry on from the next good sample, and what-if, `gcs estimate` and the
live pipeline refuse the same samples."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from gcs.core import strict_json
from gcs.core.estimation import EstimationPipeline, run_estimator
from gcs.core.estimators import registry
from gcs.core.samples import AttitudeSample, GpsSample, ImuSample

LEVEL = np.array([0.0, 0.0, -9.80665])


def good(t: float) -> ImuSample:
    return ImuSample(t, np.array([0.01, -0.02, 0.03]), LEVEL.copy(), np.array([0.2, 0.0, 0.4]), "RAW_IMU")


BAD = [
    ImuSample(1.0, np.array([math.inf, 0.0, 0.0]), LEVEL.copy()),
    ImuSample(1.01, np.array([0.0, math.nan, 0.0]), LEVEL.copy()),
    ImuSample(1.02, np.zeros(3), np.array([0.0, 0.0, 3.5e38])),
    ImuSample(1.03, np.zeros(3), LEVEL.copy(), np.array([math.nan, 0.0, 0.0])),
    ImuSample(math.nan, np.zeros(3), LEVEL.copy()),
    GpsSample(1.04, math.inf, 13.0, 40.0, 2.0, 0.1),
    GpsSample(1.05, 52.0, 13.0, 40.0, 2.0, 0.1, np.array([math.nan, 0.0, 0.0])),
    AttitudeSample(1.06, math.inf, 0.0, 0.0, "onboard"),
]


def stream() -> list:
    before = [good(k * 0.01) for k in range(100)]
    after = [good(1.1 + k * 0.01) for k in range(100)]
    return [*before, *BAD, *after, AttitudeSample(2.2, 0.0, 0.0, 0.0, "onboard")]


def test_bad_samples_are_refused_and_estimation_carries_on():
    pipeline = EstimationPipeline()
    points = [p for item in stream() for p in pipeline.feed(item)]
    assert sum(pipeline.refused.values()) == len(BAD)
    assert pipeline.refused["imu:gyro"] == 2 and pipeline.refused["attitude:angles"] == 1
    assert pipeline.imu_samples == 200  # only the good ones reached the estimators
    after = [p for p in points if p.t > 1.1]
    assert {p.source for p in after} >= set(registry.names())  # every estimator kept producing
    assert all(math.isfinite(v) for p in points for v in (p.t, p.roll, p.pitch, p.yaw))
    json.dumps([p.roll for p in points], allow_nan=False)  # strict JSON holds
    for est in pipeline.estimators.values():
        assert np.all(np.isfinite(est.quaternion))


def test_the_offline_loop_refuses_the_same_samples():
    for name in registry.names():
        estimator = registry.create(name)
        seen = [item for item, _ in run_estimator(estimator, stream())]
        assert not any(item is bad for item in seen for bad in BAD)
        assert len(seen) == 201 and np.all(np.isfinite(estimator.quaternion))


def test_an_estimator_that_raises_restarts_from_the_next_sample_and_the_others_go_on():
    """No real input makes an estimator raise today (that is the point), so a fault is injected
    into one instance; the restart builds a fresh, real one from the registry."""
    pipeline = EstimationPipeline()
    name = registry.names()[0]
    broken = pipeline.estimators[name]
    broken.set_gain("max_gap", 2.0)  # a gain the restart must keep

    def fault(sample):
        raise FloatingPointError("injected fault")

    broken.update_imu = fault  # the injected fault
    points = [p for k in range(100) for p in pipeline.feed(good(k * 0.01))]
    assert pipeline.restarts == {name: 1}
    assert pipeline.restart_reasons[name] == "FloatingPointError: injected fault"
    assert pipeline.estimators[name] is not broken and pipeline.estimators[name].gains["max_gap"] == 2.0
    assert {p.source for p in points} == set(registry.names())  # the restarted one produces again
    assert {p.source for p in points[:10]} >= set(registry.names()) - {name}  # the others never stopped


def test_strict_json_turns_non_finite_numbers_into_null_with_a_count():
    text = strict_json.dumps({"roll": [1.5, math.nan], "lag": math.inf, "ok": 2.0}, separators=(",", ":"))
    assert strict_json.loads(text) == {"roll": [1.5, None], "lag": None, "ok": 2.0, "nonfinite": 2}
    assert strict_json.loads(strict_json.dumps({"ok": 1.0})) == {"ok": 1.0}  # no flag when nothing changed
    with pytest.raises(ValueError, match="NaN"):
        strict_json.loads('{"roll": NaN}')
