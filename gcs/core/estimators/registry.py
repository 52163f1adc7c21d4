"""Estimator name → class. Classes are imported on first use, so one broken or slow estimator
module does not stop the others (or `gcs estimate --list`) from loading."""

from __future__ import annotations

import importlib

import numpy as np

from gcs.core.estimators.base import AttitudeEstimator
from gcs.core.samples import GpsSample, ImuSample

#: name → "module:Class". Add one line per estimator. The compiled classes run; each subclasses
#: its readable reference (dcm.DcmEstimator, kf.KalmanAttitudeFilter, ekf.EkfEstimator).
ESTIMATORS: dict[str, str] = {
    "dcm": "gcs.core.estimators.dcm_compiled:DcmCompiled",
    "kf": "gcs.core.estimators.kf_compiled:KalmanCompiled",
    "ekf": "gcs.core.estimators.ekf_compiled:EkfCompiled",
}


def names() -> list[str]:
    return list(ESTIMATORS)


def get(name: str) -> type[AttitudeEstimator]:
    """The estimator class registered as name; KeyError names the known ones."""
    try:
        module, cls = ESTIMATORS[name].split(":")
    except KeyError:
        raise KeyError(f"unknown estimator {name!r}; known: {', '.join(ESTIMATORS)}") from None
    estimator: type[AttitudeEstimator] = getattr(importlib.import_module(module), cls)
    return estimator


def create(name: str, preset: str | None = None, **gains: float) -> AttitudeEstimator:
    """A new estimator with a preset (None: its default) and gain overrides."""
    return get(name)(preset, **gains)


def warm() -> None:
    """Compile (or load from the disk cache) every estimator's kernels now, by running each on a
    few synthetic samples of every kind, so the first live samples do not wait for it."""
    for name in ESTIMATORS:
        estimator = create(name)
        gyro, accel, mag = np.array([0.01, -0.02, 0.03]), np.array([0.1, 0.2, -9.8]), np.array([0.2, 0.01, 0.4])
        for i in range(3):
            estimator.update_imu(ImuSample(0.01 * i, gyro, accel, mag if i != 1 else None))
        estimator.update_gps(GpsSample(0.02, 0.0, 0.0, 0.0, 5.0, 0.1, np.array([5.0, 0.5, 0.0])))
        estimator.update_imu(ImuSample(0.03, gyro, accel, mag))
        estimator.update_imu(ImuSample(0.03, gyro, accel, mag))
        estimator.attitude()
