"""What-if: re-run one estimator over a whole session with other gains, beside the original.

"What if Kp had been 0.3?" must feel interactive, so nothing is decoded twice: a `Workbench`
(gcs.sessions.workbench) keeps decoded sources and the runs with the original gains, and only
the estimator whose gains changed is re-run. Recorded gain changes are applied where they
happened, except for the gains the what-if pins.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from gcs.core.comparison import errors_against
from gcs.core.estimation import GainChange
from gcs.core.estimators import registry
from gcs.core.rotation import quat_to_euler
from gcs.core.samples import GpsSample, ImuSample
from gcs.sessions.sources import ReplaySource


@dataclass
class EstimatorRun:
    """One estimator's output over a whole source: t (s) and euler N×3 (rad: roll, pitch, yaw)
    per IMU sample, and the RMS / max error per reference (deg, roll pitch yaw)."""

    gains: dict[str, float]
    t: np.ndarray
    euler: np.ndarray
    errors: dict[str, dict[str, list[float]]]


def run_estimator(source: ReplaySource, name: str, pinned: dict[str, float]) -> EstimatorRun:
    """Run estimator `name` alone over the source's inputs, with `pinned` gains held fixed. The loop
    does only the estimator's own work; errors are computed on whole arrays afterwards."""
    preset, gains = source.estimator_config(name)
    estimator = registry.create(name, preset, **{**gains, **pinned})
    t, euler = [], []
    for item in source.inputs():  # one pass over the columns
        if isinstance(item, ImuSample):
            if estimator.update_imu(item):
                t.append(item.t)
                euler.append(quat_to_euler(estimator.quaternion.tolist()))  # floats: same angles, faster
        elif isinstance(item, GpsSample):
            estimator.update_gps(item)
        elif isinstance(item, GainChange) and item.estimator in (None, name) and item.name not in pinned:
            estimator.set_gain(item.name, item.value)
    series = np.column_stack([t, np.array(euler).reshape(-1, 3)]) if t else np.empty((0, 4))
    errors = {}
    for ref, data in source.references.items():
        err = errors_against(series, data)[:, 1:]
        if len(err):
            errors[ref] = {
                "rms": np.sqrt(np.mean(err**2, axis=0)).tolist(),
                "max": np.max(np.abs(err), axis=0).tolist(),
            }
    return EstimatorRun(dict(estimator.gains.values), series[:, 0], series[:, 1:], errors)


@dataclass
class WhatIf:
    estimator: str
    gains: dict[str, float]
    old: EstimatorRun
    new: EstimatorRun
    elapsed_s: float  # time to produce the new run (the old one is usually cached)

    def table(self) -> list[dict]:
        """RMS / max error per reference, old and new, degrees (roll, pitch, yaw)."""
        return [
            {
                "reference": ref,
                "old_rms": self.old.errors[ref]["rms"],
                "new_rms": self.new.errors[ref]["rms"],
                "old_max": self.old.errors[ref]["max"],
                "new_max": self.new.errors[ref]["max"],
            }
            for ref in self.old.errors
            if ref in self.new.errors
        ]

    def as_dict(self, max_points: int = 4000) -> dict:
        """JSON for the dashboard: decimated series in degrees and the table."""
        step = max(1, math.ceil(len(self.old.t) / max_points))
        deg = 180.0 / math.pi

        def series(run: EstimatorRun) -> dict:
            return {axis: (run.euler[::step, k] * deg).tolist() for k, axis in enumerate(("roll", "pitch", "yaw"))}

        return {
            "estimator": self.estimator,
            "gains": self.gains,
            "t": self.old.t[::step].tolist(),
            "old": series(self.old),
            "new": series(self.new),
            "table": self.table(),
            "elapsed_s": self.elapsed_s,
        }


#: (source, estimator, pinned gains) → that estimator's run; a Workbench caches it.
RunEstimator = Callable[[ReplaySource, str, dict[str, float]], EstimatorRun]


def what_if(source: ReplaySource, estimator: str, gains: dict[str, float], run: RunEstimator = run_estimator) -> WhatIf:
    """Old and new outputs of `estimator` over the source, the new one with `gains` pinned.
    KeyError: unknown estimator; GainError: a bad gain name or value."""
    registry.create(estimator, None, **gains)  # validates names and ranges before any work
    old = run(source, estimator, {})
    started = time.perf_counter()
    new = run(source, estimator, dict(gains))
    return WhatIf(estimator, dict(gains), old, new, time.perf_counter() - started)
