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

from gcs.core.estimation import run_estimator as core_run_estimator
from gcs.core.estimators import registry
from gcs.core.estimators.compiled import Compiled
from gcs.core.estimators.whole import euler_of, imu_accepted, run_whole
from gcs.core.samples import ImuSample
from gcs.sessions.scoring import scored
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
    """Run estimator `name` alone over the source's inputs, with `pinned` gains held fixed, as one
    compiled loop over the input columns (gcs.core.estimators.whole: the results of
    gcs.core.estimation.run_estimator's per-sample loop); its errors afterwards, every output
    against the references in the order they came, as the pipeline scores them (`scored`: with
    nothing pinned, the table of `gcs replay` on the source, across reboots and clock steps too)."""
    preset, gains = source.estimator_config(name)
    estimator = registry.create(name, preset, **{**gains, **pinned})
    table = source.table
    if isinstance(estimator, Compiled):
        run = run_whole(estimator, table.kind, table.imu, table.gps, table.gain_change, name, pinned)
        outputs, fed, valid = run.q, run.fed, run.valid
    else:  # an estimator without kernels (a readable reference): one call per sample
        fed = imu_accepted(table.kind, table.imu)
        outputs, valid = np.zeros((len(table.imu), 4)), np.zeros(len(table.imu), dtype=np.bool_)
        rows = iter(np.flatnonzero(fed).tolist())
        for item, is_valid in core_run_estimator(estimator, source.inputs(), name, pinned):
            if isinstance(item, ImuSample):
                row = next(rows)
                outputs[row], valid[row] = estimator.quaternion, is_valid
    errors = {ref: {"rms": s["rms"], "max": s["max"]} for ref, s in scored(table, outputs, fed).items()}
    return EstimatorRun(dict(estimator.gains.values), table.imu[valid, 0], euler_of(outputs[valid]), errors)


@dataclass
class WhatIf:
    estimator: str
    gains: dict[str, float]
    old: EstimatorRun
    new: EstimatorRun
    elapsed_s: float  # time to produce the new run (the old one is usually cached)

    def table(self) -> list[ErrorRow]:
        """RMS / max error per reference, old and new, degrees (roll, pitch, yaw)."""
        old, new = self.old.errors, self.new.errors
        return [
            ErrorRow(ref, old[ref]["rms"], new[ref]["rms"], old[ref]["max"], new[ref]["max"])
            for ref in old
            if ref in new
        ]

    def view(self, max_points: int = 4000) -> WhatIfView:
        """What the dashboard draws: series decimated to max_points, in degrees, and the table;
        a vehicle that rebooted during the source has its boots laid one after the other
        (`boots_in_line`)."""
        step = max(1, math.ceil(len(self.old.t) / max_points))
        t, cuts = boots_in_line(self.old.t[::step])

        def series(run: EstimatorRun) -> AxisSeries:
            roll, pitch, yaw = (with_gaps(np.degrees(run.euler[::step, k]), cuts) for k in range(3))
            return AxisSeries(roll, pitch, yaw)

        return WhatIfView(
            self.estimator,
            self.gains,
            with_gaps(t, cuts, at_gap=lambda before: before + BOOT_GAP_S / 2),
            series(self.old),
            series(self.new),
            self.table(),
            self.elapsed_s,
        )


#: s between one boot's last point and the next boot's first on the what-if chart's time axis.
BOOT_GAP_S = 1.0


def boots_in_line(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The chart's time axis for outputs at vehicle times `t` (s), and where each boot after the
    first starts: a vehicle that rebooted starts its clock from 0 again, and the chart (uPlot)
    wants its x ascending; it drew the boots over each other, joined by a line back from the end
    of one to the start of the next. Each later boot now follows the one before, BOOT_GAP_S on.
    So does what follows a smaller step back of the clock (a log's time glitch), where the
    comparison starts afresh too: it left x going back, and uPlot drew a line back in time."""
    x = np.array(t, dtype=float)
    cuts = np.flatnonzero(np.diff(x) < 0) + 1
    for cut in cuts:
        x[cut:] += x[cut - 1] + BOOT_GAP_S - x[cut]
    return x, cuts


def with_gaps(
    values: np.ndarray, cuts: np.ndarray, at_gap: Callable[[float], float | None] = lambda _: None
) -> list[float | None]:
    """`values` as a list with a point between two boots (before each of `cuts`): None in a
    series, where the chart breaks its line; `at_gap(the value before)` on the time axis."""
    out: list[float | None] = values.tolist()
    for cut in reversed(cuts.tolist()):
        out.insert(cut, at_gap(out[cut - 1]))  # reversed: the point before is still a number
    return out


@dataclass(frozen=True)
class ErrorRow:
    """One reference in the what-if table: RMS and max |error|, degrees (roll, pitch, yaw)."""

    reference: str
    old_rms: list[float]
    new_rms: list[float]
    old_max: list[float]
    new_max: list[float]


@dataclass(frozen=True)
class AxisSeries:
    """Z-Y-X angles in degrees, one per time of the view (None: the gap between two boots)."""

    roll: list[float | None]
    pitch: list[float | None]
    yaw: list[float | None]


@dataclass(frozen=True)
class WhatIfView:
    """A what-if as the dashboard gets it (small and picklable: it comes from a worker process)."""

    estimator: str
    gains: dict[str, float]
    t: list[float | None]  # s: vehicle time, each boot after the previous one (`boots_in_line`)
    old: AxisSeries
    new: AxisSeries
    table: list[ErrorRow]
    elapsed_s: float


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
