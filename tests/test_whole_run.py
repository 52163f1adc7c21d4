"""The whole-run path (gcs.core.estimators.whole: one compiled loop over a recording's input
columns) gives what the per-sample path gives — `run_estimator`, one update_imu call per sample,
itself equal to the readable references (test_compiled_estimators.py) — to 1e-9: the same
attitude after every IMU sample and the same validity, through GPS fixes, gain changes,
duplicates, gaps, a clock going back and refused samples; and what-if's error table on it equals
the per-sample errors."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import threading

import numpy as np
import pytest
from broad import BROAD
from test_compiled_estimators import broad_inputs

from gcs.core.estimation import GainChange, run_estimator
from gcs.core.estimators import registry, whole
from gcs.core.samples import AttitudeSample, GpsSample, ImuSample
from gcs.logs.input_table import InputTableBuilder
from gcs.runtime import replay
from gcs.runtime.replay import ReplaySession, session_table, whole_table
from gcs.sessions.sources import open_source
from gcs.sessions.whatif import run_estimator as what_if_run
from gcs.sim.recording import write_tlog

NAMES = ("dcm", "kf", "ekf")
TOL = 1e-9


def per_sample(name: str, inputs: list, pinned: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """(q after each IMU input, valid) from update_imu per sample; refused samples: not valid."""
    est = registry.create(name, None, **pinned)
    qs, valid = [], []
    fed = iter(run_estimator(est, inputs, name, tuple(pinned)))
    current = next(fed, None)
    for item in inputs:
        if not isinstance(item, ImuSample):
            if current is not None and current[0] is item:
                current = next(fed, None)
            continue
        if current is not None and current[0] is item:  # fed (not refused)
            qs.append(est.quaternion.copy())
            valid.append(current[1])
            current = next(fed, None)
        else:
            qs.append(np.zeros(4))
            valid.append(False)
    return np.array(qs).reshape(-1, 4), np.array(valid, dtype=bool)


def whole_run(name: str, inputs: list, pinned: dict[str, float]) -> whole.WholeRun:
    builder = InputTableBuilder()
    for item in inputs:
        builder.append(item)
    table = builder.build()
    est = registry.create(name, None, **pinned)
    return whole.run_whole(est, table.kind, table.imu, table.gps, table.gain_change, name, tuple(pinned))


def assert_same(name: str, inputs: list, **pinned: float) -> int:
    q, valid = per_sample(name, inputs, pinned)
    run = whole_run(name, inputs, pinned)
    assert np.array_equal(run.valid, valid)
    worst = float(np.max(np.abs(run.q[valid] - q[valid]), initial=0.0))
    assert worst <= TOL, f"{name}: quaternions differ by {worst:g}"
    return int(valid.sum())


@pytest.mark.parametrize("name", NAMES)
def test_broad_trial(name):
    assert assert_same(name, broad_inputs(next(BROAD.glob("30_*.hdf5")), count=3000)) == 3000


@pytest.mark.parametrize("name", NAMES)
def test_gaps_gain_changes_gps_and_refused_samples(name):
    """The loop returns to Python for a re-initialisation (first sample, a gap, a reboot) and a
    gain change; GPS fixes (with and without velocity, one refused), refused IMU samples (NaN, a
    gyro beyond any sensor) and references pass through the compiled loop."""
    s = broad_inputs(next(BROAD.glob("24_*.hdf5")), count=1200)
    gain = {"dcm": "kp_rp", "kf": "k_q", "ekf": "gyro_noise"}[name]
    vel = np.array([3.0, 4.0, 0.0])

    def gps(t, v, fix=3, lat=47.0):
        return GpsSample(t, lat, 8.0, 400.0, 5.0, 0.9, v, fix)

    nan_gyro = ImuSample(s[400].t + 1e-4, np.array([np.nan, 0.0, 0.0]), s[400].accel, s[400].mag)
    wild = ImuSample(s[401].t + 1e-4, np.array([200.0, 0.0, 0.0]), s[401].accel, None)
    shifted = [ImuSample(x.t + 5.0, x.gyro, x.accel, x.mag) for x in s[800:1000]]
    rebooted = [ImuSample(x.t - s[1000].t, x.gyro, x.accel, None) for x in s[1000:]]
    fixes = [gps(s[i].t, vel * (1 + 0.01 * i)) for i in range(50, 700, 10)]
    inputs: list = [*s[:50]]
    for i in range(50, 700):
        inputs.append(s[i])
        if i % 10 == 0:
            inputs.append(fixes[(i - 50) // 10])
        if i == 300:
            inputs += [s[299], GainChange(name, gain, 0.5), GainChange(None, "declination", 0.1), nan_gyro]
        if i == 400:
            inputs += [gps(s[i].t, None), gps(s[i].t + 0.001, vel, lat=200.0), AttitudeSample(s[i].t, 0.1, 0.0, 0.0)]
        if i == 401:
            inputs.append(wild)
    inputs += [*s[700:800], gps(s[799].t, vel, fix=2), *shifted, *rebooted]
    assert assert_same(name, inputs) > 1000
    assert assert_same(name, inputs, declination=math.radians(7.0)) > 1000  # pinned: the change skipped


@pytest.fixture(scope="module")
def sources(logs_dir, tmp_path_factory):
    simulated = write_tlog(tmp_path_factory.mktemp("sim") / "circuit.tlog", 40.0, script="circuit")
    return {
        "sitl": open_source(logs_dir / "arducopter-sitl-hop.BIN"),
        "px4": open_source(logs_dir / "px4-flight-sample.ulg"),
        "sim": open_source(simulated),
    }


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("which", ["sitl", "px4", "sim"])
def test_what_if_on_logs(name, which, sources):
    """What-if's run (the whole-run path) against the per-sample path over the whole log: the
    attitude of every valid sample, and the RMS / max error per reference of `gcs replay` (the
    per-sample pipeline, which scores every output it stepped, before the first valid one too)."""
    source = sources[which]
    run = what_if_run(source, name, {})
    preset, gains = source.estimator_config(name)
    est = registry.create(name, preset, **gains)
    t, qs = [], []
    for item, valid in run_estimator(est, source.inputs(), name):
        if valid and isinstance(item, ImuSample):
            t.append(item.t)
            qs.append(est.quaternion.copy())
    assert len(t) > 1000 and np.array_equal(run.t, np.array(t))
    q = np.array(qs)
    euler = np.column_stack(
        [
            np.arctan2(2 * (q[:, 0] * q[:, 1] + q[:, 2] * q[:, 3]), 1 - 2 * (q[:, 1] ** 2 + q[:, 2] ** 2)),
            np.arcsin(np.clip(2 * (q[:, 0] * q[:, 2] - q[:, 1] * q[:, 3]), -1, 1)),
            np.arctan2(2 * (q[:, 0] * q[:, 3] + q[:, 1] * q[:, 2]), 1 - 2 * (q[:, 2] ** 2 + q[:, 3] ** 2)),
        ]
    )
    assert np.max(np.abs(run.euler - euler)) <= TOL
    session = ReplaySession(source, 0, [name])
    session.run_to_end()
    table = {row["reference"]: row for row in session_table(session.pipeline)}
    assert table and run.errors.keys() == table.keys()
    for ref, row in table.items():
        assert np.allclose(run.errors[ref]["rms"], row["rms_deg"], rtol=0, atol=TOL)
        assert np.allclose(run.errors[ref]["max"], row["max_deg"], rtol=0, atol=TOL)


@pytest.mark.parametrize("which", ["sitl", "px4", "sim"])
def test_replay_table_from_whole_runs(which, sources):
    """`gcs replay --fast`'s table (whole runs) equals the per-sample pipeline's session table."""
    source = sources[which]
    session = ReplaySession(source, 0)
    session.run_to_end()
    expected = session_table(session.pipeline)
    rows, fed = whole_table(source, registry.names(), {})
    assert fed == session.pipeline.imu_samples
    assert [(r["estimator"], r["reference"], r["n"]) for r in rows] == [
        (r["estimator"], r["reference"], r["n"]) for r in expected
    ]
    for got, want in zip(rows, expected, strict=True):
        assert np.allclose(got["rms_deg"], want["rms_deg"], rtol=0, atol=TOL)
        assert np.allclose(got["max_deg"], want["max_deg"], rtol=0, atol=TOL)


def test_replay_table_runs_the_estimators_side_by_side(sources, monkeypatch):
    """Each estimator's whole run goes to a thread of its own (up to one per core), off the
    caller's thread, and the rows still come in the estimators' order."""
    threads: dict[str, int] = {}
    real = replay.run_whole

    def recorded(estimator, *args, **kwargs):
        threads[args[-1]] = threading.get_ident()
        return real(estimator, *args, **kwargs)

    monkeypatch.setattr(replay, "run_whole", recorded)
    done: list[tuple[int, int]] = []
    rows, _ = whole_table(sources["px4"], ["ekf", "dcm", "kf"], {}, lambda *p: done.append(p))
    assert sorted(threads) == ["dcm", "ekf", "kf"]
    assert threading.get_ident() not in threads.values()
    assert len(set(threads.values())) == min(3, os.cpu_count() or 1)
    assert [r["estimator"] for r in rows] == ["ekf", "dcm", "kf"]
    assert done == [(1, 3), (2, 3), (3, 3)]


@pytest.mark.parametrize("name", NAMES)
def test_what_if_of_an_estimator_without_kernels(name, sources, monkeypatch):
    """An estimator without compiled kernels (here the readable reference) still gets a what-if,
    one call per sample, equal to the compiled estimator's whole run."""
    source = sources["sitl"]
    fast = what_if_run(source, name, {})
    reference = {"dcm": "dcm:DcmEstimator", "kf": "kf:KalmanAttitudeFilter", "ekf": "ekf:EkfEstimator"}[name]
    monkeypatch.setitem(registry.ESTIMATORS, name, f"gcs.core.estimators.{reference}")
    slow = what_if_run(source, name, {})
    assert np.array_equal(slow.t, fast.t) and len(fast.t) > 1000
    assert np.max(np.abs(slow.euler - fast.euler)) <= TOL
    for ref, errors in fast.errors.items():
        assert np.allclose(slow.errors[ref]["rms"], errors["rms"], rtol=0, atol=TOL)


def test_the_workers_warm_up_compiles_the_whole_run_loop():
    """The station's worker warms up at server start: afterwards the whole-run loop and the error
    kernels hold compiled code, so the first what-if does not compile (tens of seconds cold)."""
    probe = (
        "from gcs.sessions.workbench import warm_up; from gcs.core.estimators import whole; "
        "print(len(whole.run_inputs.signatures), len(whole._attitude_errors.signatures), "
        "len(whole.euler_of.signatures))"
    )

    def compiled(code: str) -> list[int]:
        run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
        return [int(n) for n in run.stdout.split()]

    assert compiled(probe) == [0, 0, 0]
    assert all(n >= 1 for n in compiled(probe.replace("whole; ", "whole; warm_up(); "))), "not compiled"
