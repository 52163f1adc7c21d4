"""BROAD trials (../shared/data/broad) scored with the dataset's own metric, for estimator
regression tests: total RMS error over the `movement` samples, NaN skipped (data/README.md)."""

from __future__ import annotations

import math

import h5py  # the test extra installs it: a missing one fails these tests, never skips them
import numpy as np
import pytest
from conftest import DATA

from gcs.core.rotation import quat_conjugate, quat_multiply
from gcs.core.samples import ImuSample

BROAD = DATA / "broad"
#: Sensor → ENU = Q_NED_TO_ENU ⊗ (sensor → NED).
Q_NED_TO_ENU = np.array([0.0, math.sqrt(0.5), math.sqrt(0.5), 0.0])


def broad_rmse(estimator, name: str, every: int) -> float:
    """Total RMS error (deg) of `estimator` (fresh, default preset) on the BROAD trial whose name
    starts with `name`, keeping every `every`-th sample."""

    path = next(BROAD.glob(f"{name}*.hdf5"), None)
    if path is None:
        pytest.fail(f"BROAD trial {name} not in {BROAD}")
    with h5py.File(path, "r") as f:
        rate = float(f.attrs["sampling_rate"]) / every
        gyr, acc, mag = (np.asarray(f[k][::every], dtype=float) for k in ("imu_gyr", "imu_acc", "imu_mag"))
        opt, moving = np.asarray(f["opt_quat"][::every], dtype=float), np.asarray(f["movement"][::every], bool)
    q = np.empty((len(gyr), 4))
    for k in range(len(gyr)):
        estimator.update_imu(ImuSample(k / rate, gyr[k], acc[k], mag[k]))
        q[k] = estimator.quaternion
    q_enu = quat_multiply(Q_NED_TO_ENU, q.T)
    w = quat_multiply(q_enu, quat_conjugate((opt / np.linalg.norm(opt, axis=1, keepdims=True)).T))[0]
    err = 2 * np.arccos(np.clip(np.abs(w), 0.0, 1.0))
    err = err[moving & np.isfinite(err)]
    return float(np.degrees(np.sqrt(np.mean(err * err))))
