"""The compiled comparison (`CompiledComparison`, one kernel call per batch) equals the readable
`Comparison` to 1e-9 — RMS and max over the window and the session, the lag, the IMU rate, the
dropped references, the reliability — after every batch, on BROAD trials (with references around
the samples), the ArduCopter SITL hop's DataFlash log, the PX4 flight and a simulated flight, in
batches of several sizes; and over a long session where the window's and the lag's sums are
re-summed, the vehicle clock goes back, a new source appears and every buffer grows."""

from __future__ import annotations

import math

import numpy as np
import pytest
from broad import BROAD
from test_batch_stepping import stream as broad_stream
from test_compiled_estimators import log_inputs

from gcs.core.comparison import RESUM_EVERY, Comparison
from gcs.core.comparison_compiled import CompiledComparison, ReferenceRuns, fsum
from gcs.core.estimation import run_estimator
from gcs.core.estimators import registry
from gcs.core.estimators.stepping import ImuBatch
from gcs.core.lag import MIN_POINTS, SUMMED
from gcs.core.samples import AttitudeSample, ImuSample
from gcs.sessions.sources import open_source
from gcs.sim.recording import write_tlog

TOL = 1e-9


def assert_close(ours: object, ref: object, where: str = "") -> None:
    """Equal structure and values; floats within TOL (NaN where the reference has NaN)."""
    if isinstance(ref, dict):
        assert isinstance(ours, dict) and list(ours) == list(ref), where
        for key in ref:
            assert_close(ours[key], ref[key], f"{where}.{key}")
    elif isinstance(ref, list):
        assert isinstance(ours, list) and len(ours) == len(ref), where
        for k, (a, b) in enumerate(zip(ours, ref, strict=True)):
            assert_close(a, b, f"{where}[{k}]")
    elif isinstance(ref, float):
        assert type(ours) is float, (where, ours)
        assert (math.isnan(ours) and math.isnan(ref)) or abs(ours - ref) <= TOL, (where, ours, ref)
    else:
        assert type(ours) is type(ref) and ours == ref, (where, ours, ref)


def compare(inputs: list, name: str, size: int, **kw: float) -> tuple[int, Comparison]:
    """Estimator `name` over the inputs; its outputs and the references in batches of `size`
    inputs into both comparisons, as the pipeline's batch gives them; the summaries compared
    after every batch. Returns the references fed and the reference comparison, whose
    `lags_determined` counts the batches after which it had a lag."""
    est = registry.create(name)
    stepped: list[tuple[object, list[float]]] = []  # every input the pipeline takes, with the outputs after it
    for item, valid in run_estimator(est, inputs, name):
        (w, x, y, z), (roll, pitch, yaw) = est.attitude()
        stepped.append((item, [w, x, y, z, roll, pitch, yaw, float(valid), 1.0]))
    ref_c, ours = Comparison(**kw), CompiledComparison(**kw)
    fed = lags_determined = 0
    for i in range(0, len(stepped), size):
        imu: list[ImuSample] = []
        outputs: list[list[float]] = []
        runs: list = []
        lo = 0
        for item, out in stepped[i : i + size]:
            if isinstance(item, ImuSample):
                imu.append(item)
                outputs.append(out)
            elif isinstance(item, AttitudeSample):
                runs.append((lo, len(imu), item))
                lo = len(imu)
                fed += 1
        runs.append((lo, len(imu), None))
        rows = ImuBatch.of(imu).rows if imu else np.empty((0, 11))
        ref_c.add_batch(runs, rows[:, 0].tolist(), outputs)
        ours.add_batch(ReferenceRuns.of(runs), rows, np.array(outputs).reshape(-1, 9))
        assert_close(ours.summary(), ref_c.summary(), f"after input {i + size}")
        lags_determined += ref_c.lag() is not None
    ref_c.lags_determined = lags_determined  # type: ignore[attr-defined]
    return fed, ref_c


def scored(c: Comparison) -> int:
    return sum(s["n"] for s in c.summary()["references"].values())


@pytest.fixture(scope="module")
def broad() -> list:
    return broad_stream()


@pytest.mark.parametrize("size", [1, 7, 16, 100])
def test_broad_trial_with_references(broad, size):
    """BROAD trial 24 with onboard and ahrs2 references around the samples, GPS fixes, refused
    samples, a gap and a reboot (test_batch_stepping's stream)."""
    fed, ref = compare(broad, "dcm", size)
    assert fed > 300 and scored(ref) > 300  # no lag at the end: nothing since the reboot


@pytest.mark.parametrize("name", ["dcm", "kf", "ekf"])
def test_every_broad_trial(name):
    """Each shared trial, references from its optical truth at 1/3 of the IMU rate."""
    from test_compiled_estimators import broad_inputs

    for path in sorted(BROAD.glob("*.hdf5")):
        samples = broad_inputs(path, count=600)
        inputs: list = []
        for k, x in enumerate(samples):
            inputs.append(x)
            if k % 3 == 0:
                inputs.append(AttitudeSample(x.t - 0.003, 0.01 * k % 0.5, -0.2, 0.01 * k % 6.0 - 3.0, "truth"))
        fed, ref = compare(inputs, name, 16)
        assert fed == 200 and scored(ref) == 199, path  # the first is before any estimate: dropped


@pytest.fixture(scope="module")
def sitl_hop(logs_dir):
    return log_inputs(logs_dir / "arducopter-sitl-hop.BIN", 100_000)


@pytest.fixture(scope="module")
def px4_flight(logs_dir):
    return log_inputs(logs_dir / "px4-flight-sample.ulg", 6_000)


@pytest.mark.parametrize("size", [5, 16])
def test_sitl_hop(sitl_hop, size):
    """The hop's lag is compared while the vehicle flies; at the end it stands landed, where no
    lag is determined (gcs.core.lag.best_lag)."""
    fed, ref = compare(sitl_hop, "ekf", size)
    assert set(ref.summary()["references"]) >= {"onboard", "ahrs2", "truth"} and ref.lags_determined > 100
    assert ref.lag() is None


@pytest.mark.parametrize("name", ["dcm", "kf"])
def test_px4_flight(px4_flight, name):
    fed, ref = compare(px4_flight, name, 16)
    assert fed > 1000 and scored(ref) > 1000 and ref.lag() is not None


def test_simulated_flight(tmp_path):
    inputs = list(open_source(write_tlog(tmp_path / "circuit.tlog", 40.0, script="circuit")).inputs())
    fed, ref = compare(inputs, "kf", 16)
    assert scored(ref) > 1000 and ref.lag() is not None


def test_long_session_resums_regrows_and_restarts():
    """400 s at 50 Hz and a reboot: more than RESUM_EVERY removals from the window's and the lag's
    sums, buffers grown past their first size, a source first seen late (a new lane)."""
    rng = np.random.default_rng(11)
    inputs: list = []
    t, angles = 0.0, np.zeros(3)
    for k in range(26_000):
        t += rng.uniform(0.015, 0.025)
        if k == 20_000:
            t -= 300.0  # the vehicle rebooted
        angles += rng.normal(0.0, 0.01, 3)
        gyro = rng.normal(0.0, 0.1, 3)
        inputs.append(ImuSample(t, gyro, np.array([0.0, 0.0, -9.8]) + rng.normal(0, 0.1, 3), None))
        off = rng.normal(0.0, 0.02, 3)
        r, p, y = (angles + off).tolist()
        inputs.append(AttitudeSample(t + rng.uniform(-0.02, 0.02), r, p, math.remainder(y, math.tau), "onboard"))
        if k % 4 == 0:
            inputs.append(AttitudeSample(t - 0.01, r, p, 0.0, "ahrs2"))
        if k > 15_000 and k % 5 == 0:
            inputs.append(AttitudeSample(t, r, p, 0.0, "late source"))
    ours_kw = {"window": 5.0, "history": 30.0}
    fed, ref = compare(inputs, "dcm", 40, **ours_kw)
    summary = ref.summary()
    assert summary["references"]["onboard"]["n"] > 2 * RESUM_EVERY and "late source" in summary["references"]
    assert fed > (20_000 * 0.02 - 30.0) / ref.running_lag.spacing > RESUM_EVERY  # the lag's sums re-summed too
    assert (ref.running_lag.sums.reshape(SUMMED, -1)[-1] >= MIN_POINTS).any()  # PAIRED, the last summed


def test_fsum_is_math_fsum():
    rng = np.random.default_rng(5)
    for scale in (1e-290, 1e-8, 1.0, 1e8, 1e280):
        values = rng.normal(0.0, scale, 1000) * rng.choice([1.0, 1e-16, 1e16], 1000)
        assert fsum(values) == math.fsum(values.tolist())
    assert fsum(np.array([1e-16, 1.0, 1e16])) == math.fsum([1e-16, 1.0, 1e16])
    assert fsum(np.array([0.1] * 10)) == 1.0 and fsum(np.empty(0)) == 0.0
    assert math.isnan(fsum(np.array([1.0, math.nan])))
