"""Estimator name → class. Classes are imported on first use, so one broken or slow estimator
module does not stop the others (or `gcs estimate --list`) from loading."""

from __future__ import annotations

import importlib

from gcs.core.estimators.base import AttitudeEstimator

#: name → "module:Class". Add one line per estimator.
ESTIMATORS: dict[str, str] = {
    "dcm": "gcs.core.estimators.dcm:DcmEstimator",
    "kf": "gcs.core.estimators.kf:KalmanAttitudeFilter",
    "ekf": "gcs.core.estimators.ekf:EkfEstimator",
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
