"""The compiled estimators (numba kernels) equal their readable references — dcm.DcmEstimator,
kf.KalmanAttitudeFilter (on filterpy's KalmanFilter) and ekf.EkfEstimator — to 1e-9 on every
shared BROAD trial, the ArduCopter SITL hop's DataFlash log, the PX4 flight and a simulated
flight: the same attitude after every sample, the same validity and the same health figures.
Slices keep the test to seconds: every trial and file is covered, not every sample of each."""

from __future__ import annotations

import math
from dataclasses import replace

import h5py
import numpy as np
import pytest
from broad import BROAD

from bench.broad import load_trial
from bench.stress import MAGNET_AXIS, floor_magnet
from gcs.core.estimation import GainChange, run_estimator
from gcs.core.estimators import registry
from gcs.core.estimators.dcm import DcmEstimator
from gcs.core.estimators.ekf import EkfEstimator
from gcs.core.estimators.kf import KalmanAttitudeFilter
from gcs.core.samples import GpsSample, ImuSample
from gcs.sessions.sources import open_source
from gcs.sim.recording import write_tlog

REFERENCES = {"dcm": DcmEstimator, "kf": KalmanAttitudeFilter, "ekf": EkfEstimator}
TOL = 1e-9


def assert_same(name: str, inputs: list, preset: str | None = None, **gains: float) -> int:
    """Run the reference and the compiled estimator side by side; returns the IMU samples compared."""
    ref, fast = REFERENCES[name](preset, **gains), registry.create(name, preset, **gains)
    assert type(fast) is not REFERENCES[name] and isinstance(fast, REFERENCES[name])
    n, worst = 0, 0.0
    ref_run, fast_run = run_estimator(ref, inputs, name), run_estimator(fast, inputs, name)
    for (item, valid_ref), (_, valid_fast) in zip(ref_run, fast_run, strict=True):
        assert valid_ref == valid_fast
        if isinstance(item, ImuSample):
            n += 1
            worst = max(worst, float(np.max(np.abs(ref.quaternion - fast.quaternion))))
    assert worst <= TOL, f"{name}: quaternions differ by {worst:g}"
    assert_same_health(ref.health(), fast.health())
    assert fast.gains.values == ref.gains.values
    return n


def assert_same_health(ref: dict, fast: dict) -> None:
    assert list(fast) == list(ref)
    for key, value in ref.items():
        assert type(fast[key]) is type(value), key
        if isinstance(value, str | bool):
            assert fast[key] == value, key
        else:
            assert np.allclose(fast[key], value, rtol=0.0, atol=TOL), (key, fast[key], value)


def broad_inputs(path, every: int = 6, count: int = 2000) -> list[ImuSample]:
    """`count` samples of a BROAD trial at every `every`-th sample (47.6 Hz), from its middle
    third on, where it moves."""
    with h5py.File(path, "r") as f:
        rate = float(f.attrs["sampling_rate"]) / every
        gyr, acc, mag = (np.asarray(f[k][::every], dtype=float) for k in ("imu_gyr", "imu_acc", "imu_mag"))
    start = max(0, min(len(gyr) // 3, len(gyr) - count))
    return [ImuSample(k / rate, gyr[k], acc[k], mag[k]) for k in range(start, min(len(gyr), start + count))]


TRIALS = sorted(BROAD.glob("*.hdf5"))


def test_every_broad_trial_is_here():
    assert len(TRIALS) == 6


@pytest.mark.parametrize("name", REFERENCES)
@pytest.mark.parametrize("trial", TRIALS, ids=lambda p: p.name[:2])
def test_broad_trials(name, trial):
    assert assert_same(name, broad_inputs(trial)) == 2000


@pytest.mark.parametrize(
    ("name", "preset"), [(n, p) for n, cls in REFERENCES.items() for p in cls.PRESETS if p != cls.DEFAULT_PRESET]
)
def test_other_presets_on_the_magnet_trial(name, preset):
    trial = next(BROAD.glob("30_*.hdf5"))
    assert assert_same(name, broad_inputs(trial, count=1500), preset) == 1500


@pytest.mark.parametrize("name", REFERENCES)
def test_body_fixed_magnet(name):
    """A 100 µT magnet fixed to the sensor from the 1000th sample on: the hard-iron offset is
    learned, and the heading's weight comes back after it (magnetic.py), alike in both."""
    samples = broad_inputs(next(BROAD.glob("02_*.hdf5")))
    offset = 100.0 * MAGNET_AXIS
    inputs = [*samples[:1000], *(ImuSample(x.t, x.gyro, x.accel, x.mag + offset) for x in samples[1000:])]
    assert assert_same(name, inputs) == 2000
    fast = registry.create(name)
    for x in inputs:
        fast.update_imu(x)
    learned = np.asarray(fast.health()["mag_offset"])
    assert np.linalg.norm(learned - offset) < 10.0, learned


@pytest.mark.parametrize("name", REFERENCES)
def test_gain_changes_duplicates_gaps_and_a_clock_going_back(name):
    """set_gain mid-run, a repeated timestamp, a gap longer than max_gap and a reboot: the same
    re-initialisations (and reasons), the same gains taken at the same sample."""
    samples = broad_inputs(next(BROAD.glob("24_*.hdf5")), count=1200)
    gain = {"dcm": "kp_rp", "kf": "k_q", "ekf": "gyro_noise"}[name]
    s = samples
    shifted = [ImuSample(x.t + 5.0, x.gyro, x.accel, x.mag) for x in s[800:1000]]  # a gap
    rebooted = [ImuSample(x.t - s[1000].t, x.gyro, x.accel, None) for x in s[1000:]]  # back, no mag
    inputs = [*s[:300], s[299], GainChange(name, gain, 0.5), *s[300:800], *shifted, *rebooted]
    assert assert_same(name, inputs) == len(s) + 1
    assert_same(name, inputs, declination=math.radians(7.0))


@pytest.mark.parametrize("name", REFERENCES)
def test_a_start_waiting_for_its_field(name):
    """A start on field-less samples, as ArduPilot's first RAW_IMU after a boot: held until the
    field comes, its tilt carried by the gyro through a fast rotation meanwhile."""
    samples = broad_inputs(next(BROAD.glob("07_*.hdf5")), count=600)
    inputs = [replace(x, mag=None) for x in samples[:20]] + samples[20:]
    assert assert_same(name, inputs) == len(samples)


def log_inputs(path, imu_samples: int) -> list:
    """The estimation inputs of a log (IMU, GPS, references, gain changes) up to `imu_samples`
    IMU samples."""
    out, n = [], 0
    for item in open_source(path).inputs():
        out.append(item)
        n += isinstance(item, ImuSample)
        if n >= imu_samples:
            break
    return out


@pytest.fixture(scope="module")
def sitl_hop(logs_dir):
    return log_inputs(logs_dir / "arducopter-sitl-hop.BIN", 100_000)  # all of it: IMU at 25 Hz


@pytest.fixture(scope="module")
def px4_flight(logs_dir):
    return log_inputs(logs_dir / "px4-flight-sample.ulg", 6_000)


@pytest.mark.parametrize("name", REFERENCES)
def test_sitl_hop_dataflash(name, sitl_hop):
    assert any(isinstance(x, GpsSample) for x in sitl_hop)  # GPS aiding is compared too
    assert assert_same(name, sitl_hop) == 2450


@pytest.mark.parametrize("name", REFERENCES)
def test_px4_flight(name, px4_flight):
    assert assert_same(name, px4_flight) == 6_000


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    path = write_tlog(tmp_path_factory.mktemp("sim") / "circuit.tlog", 40.0, script="circuit")
    return list(open_source(path).inputs())


@pytest.mark.parametrize("name", REFERENCES)
def test_simulated_flight(name, simulated):
    assert assert_same(name, simulated) > 1000


@pytest.mark.parametrize("name", REFERENCES)
def test_floor_magnet_heading_relearn(name):
    """Trial 30 over bench.stress's floor magnet, from its start: the reference taken at rest over
    the magnet is the disturbed one, and after 20 s of fast turning with the field steadily off the
    heading it is set aside as rejected (magnetic.py, MagneticHeading._new_heading), alike in both."""
    trial = floor_magnet(load_trial(next(BROAD.glob("30_*.hdf5")), 6))
    t, gyr, acc, mag = (np.asarray(trial[k]) for k in ("t", "imu_gyr", "imu_acc", "imu_mag"))
    inputs = [ImuSample(float(t[k]), gyr[k], acc[k], mag[k]) for k in range(4000)]
    assert assert_same(name, inputs) == 4000
    ref = REFERENCES[name]()
    for x in inputs:
        ref.update_imu(x)
    assert ref.mag.rejected is not None
