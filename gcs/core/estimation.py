"""One vehicle's estimation inputs → every estimator → comparison with the references.

`EstimationPipeline` is synchronous and deterministic: the live ground station and the replay
of a recording feed it the same inputs (samples, and gain changes at the input position where
they were applied) in the same order and get the same numbers.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Collection, Iterable, Iterator, Sequence
from dataclasses import dataclass
from itertools import chain, repeat
from typing import NamedTuple, TypedDict

from gcs.core.comparison import BatchRuns, Comparison, ComparisonSummary
from gcs.core.comparison_compiled import NO_OUTPUTS, NO_ROWS, CompiledComparison, ReferenceRuns
from gcs.core.estimators import registry
from gcs.core.estimators.base import AttitudeEstimator, HealthValue
from gcs.core.estimators.compiled import Compiled
from gcs.core.estimators.stepping import (
    EULER,
    OUT,
    BatchAttitudes,
    Fault,
    ImuBatch,
    ImuRow,
    accepted_rows,
    imu_sample_of,
    step_batch,
    step_samples,
)
from gcs.core.gains import PresetFile
from gcs.core.plausibility import refusal
from gcs.core.samples import AttitudeSample, GpsSample, ImuSample


@dataclass(frozen=True, slots=True)
class GainChange:
    """Set gain `name` to `value` on `estimator` (None: every estimator that has it) here."""

    estimator: str | None
    name: str
    value: float


#: What an estimation pipeline consumes, in order.
EstimationInput = ImuSample | GpsSample | AttitudeSample | GainChange


class AttitudePoint(NamedTuple):
    """One attitude of one source at a vehicle time: a reference ("onboard", "ahrs2",
    "truth") or an estimator (its name). Angles in rad, Z-Y-X. A named tuple: the live
    estimation makes ~2.5 per message, and a frozen dataclass cost 2-3 times as much to build."""

    t: float
    source: str
    roll: float
    pitch: float
    yaw: float


class EstimatorSummary(TypedDict):
    """One estimator in `EstimationPipeline.summary()`."""

    preset: str
    gains: dict[str, float]
    health: dict[str, HealthValue]
    comparison: ComparisonSummary


class LatestAttitude(TypedDict):
    """The latest attitude of one source in `EstimationPipeline.summary()`, degrees."""

    t: float
    roll_deg: float
    pitch_deg: float
    yaw_deg: float


class PipelineSummary(TypedDict):
    """`EstimationPipeline.summary()`."""

    imu_samples: int
    declination_rad: float | None
    estimators: dict[str, EstimatorSummary]
    latest: dict[str, LatestAttitude]


class EstimationPipeline:
    def __init__(
        self,
        estimators: dict[str, AttitudeEstimator] | None = None,
        window: float = 10.0,
    ) -> None:
        self.estimators = estimators if estimators is not None else {n: registry.create(n) for n in registry.names()}
        #: s of vehicle time over which each comparison judges its IMU rate and reliability
        self.window = window
        self.comparisons = {name: CompiledComparison(window=window) for name in self.estimators}
        self.latest: dict[str, AttitudePoint] = {}
        self.imu_samples = 0
        self.declination: float | None = None  # the vehicle's, once a GainChange for every estimator set it
        self.refused: Counter[str] = Counter()  # implausible inputs, by reason
        self.restarts: Counter[str] = Counter()  # estimators restarted after a non-finite state or an error
        self.restart_reasons: dict[str, str] = {}  # estimator -> why it last restarted

    def feed(self, item: EstimationInput) -> list[AttitudePoint]:
        """Fuse one input; returns the attitudes it produced (none, one reference, or one per
        valid estimator after an IMU sample). An implausible sample (gcs.core.plausibility) is
        counted in `refused` and goes nowhere."""
        if not isinstance(item, GainChange):
            reason = refusal(item)
            if reason is not None:
                self.refused[reason] += 1
                return []
        if isinstance(item, ImuSample):
            return self._imu(item)
        if isinstance(item, GpsSample):
            for name, est in list(self.estimators.items()):
                try:
                    est.update_gps(item)
                except Exception as exc:  # one estimator's fault: it restarts, the others go on
                    self._restart(name, est, f"{type(exc).__name__}: {exc}")
            return []
        if isinstance(item, GainChange):
            self._gain_change(item)
            return []
        return [self._reference(item)]

    def feed_many(self, items: Sequence[EstimationInput | ImuRow]) -> list[AttitudePoint]:
        """`feed` of every item in order: the same numbers and the same points, in the same order.
        An IMU sample may come as its ImuBatch row (`ImuRow`, the live path's).
        The IMU samples between two inputs that reach the estimators otherwise (a GPS fix, a gain
        change) are stepped as one batch per estimator (gcs.core.estimators.stepping), and the
        comparisons get each estimator's outputs in their order with the references: the live
        estimation's tick in a few compiled calls instead of one per sample and estimator."""
        points: list[AttitudePoint] = []
        segment: list[ImuSample | ImuRow | AttitudeSample] = []
        for item in items:
            if isinstance(item, GainChange | GpsSample):
                if segment:
                    points += self._segment(segment)
                    segment = []
                points += self.feed(item)
            else:
                segment.append(item)
        if segment:
            points += self._segment(segment)
        return points

    def _segment(self, items: list[ImuSample | ImuRow | AttitudeSample]) -> list[AttitudePoint]:
        """IMU samples (or their rows) and references in arrival order → the points `feed` gives."""
        imu = [item for item in items if not isinstance(item, AttitudeSample)]
        if not imu:  # references only
            return [point for item in items if isinstance(item, AttitudeSample) for point in self.feed(item)]
        batch = ImuBatch.of(imu)
        accepted = accepted_rows(batch.rows)
        if not accepted.all():
            batch = batch.take(accepted)
        # the plausible inputs as runs of IMU rows, each followed by a reference (None: the last)
        runs: BatchRuns = []
        plausible = accepted.tolist()
        r = lo = kept = 0
        for item in items:
            if not isinstance(item, AttitudeSample):
                if plausible[r]:
                    kept += 1
                else:  # the same rule, for its reason
                    self.refused[refusal(imu_sample_of(item) if isinstance(item, tuple) else item) or "imu"] += 1
                r += 1
                continue
            reason = refusal(item)
            if reason is not None:
                self.refused[reason] += 1
                continue
            runs.append((lo, kept, item))
            lo = kept
        runs.append((lo, kept, None))
        self.imu_samples += kept
        outputs = {name: self._step(name, batch) for name in list(self.estimators)}
        references = ReferenceRuns.of(runs)
        for name, out in outputs.items():
            self.comparisons[name].add_batch(references, batch.rows, out.rows)
        return self._points(runs, batch.rows[:, 0].tolist(), outputs)

    def _points(self, runs: BatchRuns, times: list[float], outputs: dict[str, BatchAttitudes]) -> list[AttitudePoint]:
        """The points of a batch, in the order feed gives them: per sample every estimator with a
        valid attitude, references where they arrived. When every estimator gave a valid attitude
        on every row (all but a start or a restart), each one's points are made by one `map`
        over its columns and interleaved by `zip`, not by a Python loop per point."""
        latest = self.latest
        columns = {name: out.rows[:, EULER:OUT].T.tolist() for name, out in outputs.items()}
        if not all(all(valid) and all(stepped) for _, _, _, valid, stepped in columns.values()):
            return self._points_one_by_one(runs, times, columns)
        each = [
            list(map(AttitudePoint, times, repeat(name), roll, pitch, yaw))
            for name, (roll, pitch, yaw, _, _) in columns.items()
        ]
        shown = list(chain.from_iterable(zip(*each)))
        if len(runs) == 1:  # no reference
            latest.update((name, series[-1]) for name, series in zip(columns, each, strict=True) if series)
            return shown
        width = len(each)
        points: list[AttitudePoint] = []
        for lo, hi, ref in runs:
            if hi > lo:
                points += shown[lo * width : hi * width]
                latest.update((name, series[hi - 1]) for name, series in zip(columns, each, strict=True))
            if ref is not None:
                latest[ref.source] = point = AttitudePoint(ref.t, ref.source, ref.roll, ref.pitch, ref.yaw)
                points.append(point)
        return points

    def _points_one_by_one(
        self, runs: BatchRuns, times: list[float], columns: dict[str, list[list[float]]]
    ) -> list[AttitudePoint]:
        """`_points`, a point at a time (some estimator not valid on some row)."""
        points: list[AttitudePoint] = []
        latest = self.latest
        for lo, hi, ref in runs:
            for r in range(lo, hi):
                t = times[r]
                for name, (roll, pitch, yaw, valid, stepped) in columns.items():
                    if valid[r] and stepped[r]:
                        latest[name] = point = AttitudePoint(t, name, roll[r], pitch[r], yaw[r])
                        points.append(point)
            if ref is not None:
                latest[ref.source] = point = AttitudePoint(ref.t, ref.source, ref.roll, ref.pitch, ref.yaw)
                points.append(point)
        return points

    def _step(self, name: str, batch: ImuBatch) -> BatchAttitudes:
        """Estimator `name` over the batch; a fault restarts it, as `_imu` does, and the new one
        goes on from the next sample."""
        out = BatchAttitudes.empty(len(batch))
        start = 0
        while True:
            est = self.estimators[name]
            fault: Fault | None
            if isinstance(est, Compiled):
                fault = step_batch(est, batch, start, out)
            else:
                fault = step_samples(est, batch, start, out)
            if fault is None:
                return out
            self._restart(name, est, fault.reason)
            start = fault.row + 1

    def feed_all(self, items: Iterable[EstimationInput]) -> None:
        for item in items:
            self.feed(item)

    def _gain_change(self, change: GainChange) -> None:
        if change.estimator is None:
            if change.name == "declination":
                self.declination = change.value
            targets = [name for name, est in self.estimators.items() if change.name in est.gains.declarations]
        else:
            targets = [change.estimator] if change.estimator in self.estimators else []
        for name in targets:
            self.set_gain(name, change.name, change.value)

    def _imu(self, sample: ImuSample) -> list[AttitudePoint]:
        self.imu_samples += 1
        points = []
        t, comparisons, latest, isfinite = sample.t, self.comparisons, self.latest, math.isfinite  # per sample: locals
        for name, est in list(self.estimators.items()):
            try:
                valid = est.update_imu(sample)
            except Exception as exc:  # one estimator's fault: it restarts, the others go on
                self._restart(name, est, f"{type(exc).__name__}: {exc}")
                continue
            q, euler = est.attitude()  # plain floats from here on: numpy scalars are slow
            w, x, y, z = q
            if not isfinite(w + x + y + z):  # a NaN or an infinity anywhere (|q| = 1 otherwise)
                self._restart(name, est, f"non-finite state at t={t:.3f} s")
                continue
            comparisons[name].add_estimate(t, q, euler)
            if valid:
                latest[name] = point = AttitudePoint(t, name, *euler)
                points.append(point)
        return points

    def _restart(self, name: str, broken: AttitudeEstimator, reason: str) -> None:
        """A filter whose state went non-finite, or that raised, starts again with the same preset
        and gains from the next sample; the count and the reason are in the status."""
        self.estimators[name] = registry.create(name, broken.preset, **broken.gains.values)
        self.restarts[name] += 1
        self.restart_reasons[name] = reason

    def _reference(self, ref: AttitudeSample) -> AttitudePoint:
        references = ReferenceRuns.of([(0, 0, ref)])
        for comparison in self.comparisons.values():
            comparison.add_batch(references, NO_ROWS, NO_OUTPUTS)
        point = AttitudePoint(ref.t, ref.source, ref.roll, ref.pitch, ref.yaw)
        self.latest[ref.source] = point
        return point

    def set_gain(self, estimator: str, name: str, value: float) -> tuple[float, float]:
        """Change one gain of one estimator now; GainError/KeyError name what is wrong."""
        if estimator not in self.estimators:
            raise KeyError(f"unknown estimator {estimator!r}; running: {', '.join(self.estimators)}")
        return self.estimators[estimator].set_gain(name, value)

    def summary(self) -> PipelineSummary:
        """Per estimator: preset, gains, health and the comparison; latest attitude per source."""
        return {
            "imu_samples": self.imu_samples,
            "declination_rad": self.declination,
            "estimators": {
                name: {
                    "preset": est.preset,
                    "gains": dict(est.gains.values),
                    "health": est.health(),
                    "comparison": self.comparisons[name].summary(),
                }
                for name, est in self.estimators.items()
            },
            "latest": {
                source: {
                    "t": p.t,
                    "roll_deg": math.degrees(p.roll),
                    "pitch_deg": math.degrees(p.pitch),
                    "yaw_deg": math.degrees(p.yaw),
                }
                for source, p in self.latest.items()
            },
        }


def pipeline_from(presets: Iterable[PresetFile] = ()) -> EstimationPipeline:
    """Every registered estimator; one a preset file names starts from that file's preset and
    gains (the live station with `--preset-file`). KeyError/GainError name a bad file's problem."""
    chosen = {p.estimator: p for p in presets}
    for name in chosen:
        registry.get(name)
    return EstimationPipeline(
        {
            name: registry.create(name, chosen[name].preset, **chosen[name].gains)
            if name in chosen
            else registry.create(name)
            for name in registry.names()
        }
    )


def run_estimator(
    estimator: AttitudeEstimator,
    inputs: Iterable[EstimationInput],
    name: str | None = None,
    pinned: Collection[str] = (),
) -> Iterator[tuple[EstimationInput, bool]]:
    """Feed `inputs` in order to one estimator and yield each with whether the attitude is valid
    after it (read the estimator's state then). IMU and GPS samples are fused; a GainChange for
    estimator `name` (or for every estimator) is applied unless its gain is `pinned`; references
    pass through; implausible samples are dropped, as the pipeline drops them. The one loop behind
    `gcs estimate`, what-if and `compare_stream`."""
    valid = False
    for item in inputs:
        if not isinstance(item, GainChange) and refusal(item) is not None:
            continue  # as the pipeline refuses it
        if isinstance(item, ImuSample):
            valid = estimator.update_imu(item)
        elif isinstance(item, GpsSample):
            estimator.update_gps(item)
        elif isinstance(item, GainChange):
            if item.estimator in (None, name) and item.name not in pinned and item.name in estimator.gains.declarations:
                estimator.set_gain(item.name, item.value)
        yield item, valid


def compare_stream(
    samples: Iterable[EstimationInput],
    estimator: AttitudeEstimator,
    comparison: Comparison | None = None,
) -> Comparison:
    """Run estimator over a sample stream (IMU, GPS, references, gain changes in arrival order) and compare.

    The same calls the live pipeline makes, so its result equals the live numbers.
    """
    comparison = comparison or Comparison()
    for item, _ in run_estimator(estimator, samples):
        if isinstance(item, ImuSample):
            comparison.add_estimate(item.t, estimator.quaternion)
        elif isinstance(item, AttitudeSample):
            comparison.add_reference(item)
    return comparison
