"""The live estimation's batch (`EstimationPipeline.feed_many`: a tick's IMU samples stepped per
estimator in one compiled call, the comparisons fed per batch) gives what `feed` gives one input
at a time: the same points in the same order, the same summary (comparisons, lag, health), the
same refusals and restarts, with gain changes, GPS fixes, gaps, a clock going back, refused
samples, an estimator going non-finite and one raising, in batches of any size."""

from __future__ import annotations

import math

import numpy as np
import pytest
from broad import BROAD
from test_compiled_estimators import broad_inputs

from gcs.core.estimation import EstimationPipeline, GainChange
from gcs.core.estimators import dcm_compiled, registry
from gcs.core.estimators import kernels as k
from gcs.core.samples import AttitudeSample, GpsSample, ImuSample


def stream() -> list:
    """BROAD trial 24 at 47.6 Hz with what the live link brings besides: references (onboard,
    ahrs2) around the samples, GPS fixes, gain changes, refused samples, a gap, a reboot."""
    s = broad_inputs(next(BROAD.glob("24_*.hdf5")), count=1200)
    vel = np.array([3.0, 4.0, 0.0])

    def gps(t, v, fix=3, lat=47.0):
        return GpsSample(t, lat, 8.0, 400.0, 5.0, 0.9, v, fix)

    out: list = []
    for i, x in enumerate(s[:800]):
        out.append(x)
        if i % 3 == 0:
            out.append(AttitudeSample(x.t - 0.004, 0.01 * math.sin(i), 0.02, 0.1 * i % 3.0, "onboard"))
        if i % 7 == 0:
            out.append(AttitudeSample(x.t + 0.002, 0.0, 0.01 * math.cos(i), 0.5, "ahrs2"))
        if i % 25 == 0:
            out.append(gps(x.t, vel * (1 + 0.01 * i)))
        if i == 300:
            out += [s[299], GainChange("dcm", "kp_rp", 0.5), GainChange(None, "declination", 0.1)]
            out.append(ImuSample(x.t + 1e-4, np.array([np.nan, 0.0, 0.0]), x.accel, x.mag))
        if i == 401:
            out += [ImuSample(x.t + 1e-4, np.array([200.0, 0.0, 0.0]), x.accel, None), gps(x.t, vel, lat=200.0)]
        if i == 500:
            out += [GainChange("kf", "k_q", 0.2), GainChange("ekf", "gyro_noise", 0.01)]
    out += [ImuSample(x.t + 5.0, x.gyro, x.accel, None if j % 2 else x.mag) for j, x in enumerate(s[800:1000])]
    out += [ImuSample(x.t - s[1000].t, x.gyro, x.accel, x.mag) for x in s[1000:]]
    return out


def outputs(pipeline: EstimationPipeline, points: list) -> tuple:
    return (
        [(p.t, p.source, p.roll, p.pitch, p.yaw) for p in points],
        repr(pipeline.summary()),
        dict(pipeline.refused),
        dict(pipeline.restarts),
        dict(pipeline.restart_reasons),
    )


def one_by_one(inputs: list, poke=None) -> tuple:
    pipeline = EstimationPipeline()
    points = []
    for i, item in enumerate(inputs):
        if poke is not None:
            poke(pipeline, i)
        points += pipeline.feed(item)
    return outputs(pipeline, points)


def batched(inputs: list, size: int, poke=None) -> tuple:
    pipeline = EstimationPipeline()
    points = []
    for i in range(0, len(inputs), size):
        if poke is not None:
            poke(pipeline, i)
        points += pipeline.feed_many(inputs[i : i + size])
    return outputs(pipeline, points)


@pytest.fixture(scope="module")
def inputs() -> list:
    return stream()


@pytest.mark.parametrize("size", [1, 5, 16, 64, 100_000])
def test_batches_equal_one_input_at_a_time(inputs, size):
    """Segments without IMU samples go through `feed`, the others are stepped as batches."""
    expected = one_by_one(inputs)
    assert len(expected[0]) > 3000 and expected[2]  # points, and refused samples among them
    assert batched(inputs, size) == expected


def test_a_non_finite_estimator_restarts_at_the_same_sample(inputs):
    """kf's state made NaN between two batches: it restarts on the batch's first sample in both
    paths, and the others go on."""
    at = 64 * 10

    def poke(pipeline, i):
        if i == at:
            pipeline.estimators["kf"].s[k.BASE :] = math.nan

    expected = one_by_one(inputs, poke)
    assert expected[3] == {"kf": 1} and "non-finite" in expected[4]["kf"]
    assert batched(inputs, 64, poke) == expected


def test_an_estimator_that_raises_restarts_at_the_same_sample(inputs, monkeypatch):
    """dcm raising in its re-initialisation after the gap (mid-batch): restarted there, both paths."""
    real = dcm_compiled.DcmCompiled._after_step

    def after_step(self, code, sample):
        if code == k.GAP:
            raise ValueError("broken")
        return real(self, code, sample)

    monkeypatch.setattr(dcm_compiled.DcmCompiled, "_after_step", after_step)
    expected = one_by_one(inputs)
    assert expected[3] == {"dcm": 1} and expected[4]["dcm"] == "ValueError: broken"
    for size in (16, 100_000):
        assert batched(inputs, size) == expected


@pytest.mark.parametrize("name", ["dcm", "kf", "ekf"])
def test_estimators_without_kernels_are_stepped_per_sample(inputs, name, monkeypatch):
    """A reference (non-compiled) estimator in the pipeline: the batch steps it per sample, the
    same as `feed`."""
    reference = {"dcm": "dcm:DcmEstimator", "kf": "kf:KalmanAttitudeFilter", "ekf": "ekf:EkfEstimator"}[name]
    monkeypatch.setitem(registry.ESTIMATORS, name, f"gcs.core.estimators.{reference}")
    part = inputs[:1500]
    assert batched(part, 64) == one_by_one(part)
