"""`gcs sweep`: the gains of one estimator that minimise its error over many flights.

The optimiser is scipy's `differential_evolution` (scipy is already a dependency; its `workers`
argument takes any map-like callable, which is where the trials go to Dask): each generation is a
population of gain sets, and one task per training flight scores every set of the generation on
that flight, so a flight is decoded once per worker (the worker's `Workbench` keeps it) and only
a few floats come back. A flight's score is the total RMS error, sqrt of the mean of the squared
roll, pitch and yaw RMS (deg), of `gcs.sessions.whatif.run_estimator` (what-if's run, the one
error function) against the objective's reference. The "current" gains of a flight are those
it was recorded with (a session's meta.json), else the estimator's default preset.
"""

from __future__ import annotations

import errno
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from distributed import Client
from scipy.optimize import differential_evolution

from gcs.batch import dataset
from gcs.batch.cluster import completed
from gcs.batch.flight import facts
from gcs.batch.objective import OBJECTIVES, GainRange, score
from gcs.core.estimators import registry
from gcs.core.gains import PresetFile
from gcs.logs.logfile import InputError
from gcs.sessions import layout
from gcs.sessions.whatif import run_estimator
from gcs.sessions.workbench import workbench


@dataclass(frozen=True)
class FlightScores:
    """What a sweep task returns: one flight's score per gain set (NaN: unreadable or no reference)."""

    path: str
    vehicle: str
    scores: list[float]
    reason: str = ""


def score_flight(path: str, estimator: str, reference: str, gain_sets: list[dict[str, float]]) -> FlightScores:
    """The task: every gain set (pinned over the flight's own gains; {} = its current gains) on one flight."""
    try:
        source = workbench().source(path)
    except InputError as exc:
        return FlightScores(path, "unknown", [math.nan] * len(gain_sets), str(exc))
    vehicle = facts(source).vehicle
    return FlightScores(
        path, vehicle, [score(run_estimator(source, estimator, g).errors, reference) for g in gain_sets]
    )


class Trials:
    """Scores gain sets on the cluster; a map-like `workers` for scipy: `trials(func, xs)` scores
    every x (a vector in `ranges` order) on every flight and returns the mean per x (func, scipy's
    own wrapper of the objective, is not needed: the scoring is `score_flight`)."""

    def __init__(self, client: Client, flights: list[str], estimator: str, reference: str, ranges: list[GainRange]):
        self.client, self.flights, self.estimator, self.reference = client, flights, estimator, reference
        self.ranges = ranges
        self.gain_sets: list[dict[str, float]] = []
        self.scores: list[list[float]] = []  # per trial: per flight
        self.vehicles: dict[str, str] = {}

    def evaluate(self, flights: Sequence[str], gain_sets: list[dict[str, float]]) -> dict[str, FlightScores]:
        futures = [
            self.client.submit(score_flight, f, self.estimator, self.reference, gain_sets, pure=False) for f in flights
        ]
        out = {}
        result: FlightScores
        for result in completed(futures):
            out[result.path] = result
            self.vehicles[result.path] = result.vehicle
        return out

    def __call__(self, func: Callable, xs: Sequence[Sequence[float]]) -> list[float]:
        sets = [{r.name: float(v) for r, v in zip(self.ranges, x)} for x in xs]
        by_flight = self.evaluate(self.flights, sets)
        for k, gains in enumerate(sets):
            self.gain_sets.append(gains)
            self.scores.append([by_flight[f].scores[k] for f in self.flights])
        means = [_mean(s) for s in self.scores[-len(sets) :]]
        return [m if math.isfinite(m) else 1e9 for m in means]


def _mean(values: Sequence[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return sum(finite) / len(finite) if finite else math.nan


@dataclass(frozen=True)
class FlightOutcome:
    path: str
    vehicle: str
    holdout: bool
    current: float  # score with the flight's current gains
    best: float  # score with the best gains


@dataclass(frozen=True)
class SweepResult:
    estimator: str
    objective: str
    best: dict[str, float]
    best_score: float  # mean over the training flights
    per_vehicle: dict[str, dict[str, float]]  # vehicle → its best trial's gains
    flights: list[FlightOutcome]
    trials: int
    folder: Path

    def mean(self, holdout: bool, which: str) -> float:
        return _mean([getattr(f, which) for f in self.flights if f.holdout == holdout])


def population(trials: int, dimensions: int) -> tuple[int, int]:
    """(popsize multiplier, generations after the first) for about `trials` evaluations: a
    population of at least 5 (scipy's minimum) and 5 per gain, as many generations as fit."""
    members = max(5, min(trials, 5 * dimensions))
    popsize = math.ceil(members / dimensions)
    return popsize, max(0, trials // (popsize * dimensions) - 1)


def sweep(
    client: Client,
    flights: list[str],
    holdout: list[str],
    estimator: str,
    ranges: list[GainRange],
    objective: str,
    trials: int,
    out: str | os.PathLike,
    seed: int = 0,
) -> SweepResult:
    """Search `ranges` on `flights`, score best and current gains on flights + holdout, write the
    sweep's tables and preset into DATASET/sweeps/<estimator>-<stamp>/."""
    reference = OBJECTIVES[objective]
    runner = Trials(client, flights, estimator, reference, ranges)
    popsize, generations = population(trials, len(ranges))
    found = differential_evolution(
        _scored_by_trials,
        [(r.low, r.high) for r in ranges],
        workers=runner,
        updating="deferred",
        popsize=popsize,
        maxiter=generations,
        init="latinhypercube",
        polish=False,
        tol=0,
        seed=seed,
    )
    best = {r.name: float(v) for r, v in zip(ranges, found.x)}
    means = [_mean(s) for s in runner.scores]
    per_vehicle = {}
    for vehicle in sorted(set(runner.vehicles[f] for f in flights)):
        cols = [k for k, f in enumerate(flights) if runner.vehicles[f] == vehicle]
        vmeans = [_mean([s[c] for c in cols]) for s in runner.scores]
        k = int(np.nanargmin(np.array(vmeans, dtype=float))) if any(math.isfinite(m) for m in vmeans) else 0
        per_vehicle[vehicle] = runner.gain_sets[k]
    final = runner.evaluate([*flights, *holdout], [best, {}])
    outcomes = [
        FlightOutcome(p, final[p].vehicle, p in holdout, final[p].scores[1], final[p].scores[0])
        for p in [*flights, *holdout]
    ]
    folder = Path(out) / dataset.SWEEPS / f"{estimator}-{time.strftime('%Y%m%d-%H%M%S')}"
    result = SweepResult(
        estimator,
        objective,
        best,
        float(np.nanmin(np.array(means, dtype=float))),
        per_vehicle,
        outcomes,
        len(runner.gain_sets),
        folder,
    )
    return replace(result, folder=write_sweep(result, runner))


def _scored_by_trials(x: Sequence[float]) -> float:
    raise RuntimeError("gain sets are scored on the cluster by Trials, never one by one")


def preset_of(result: SweepResult) -> PresetFile:
    base = registry.get(result.estimator).DEFAULT_PRESET
    note = (
        f"gcs sweep {result.objective}: {result.trials} trials over "
        f"{sum(not f.holdout for f in result.flights)} flights, mean {result.best_score:.3f} deg"
    )
    return PresetFile(result.estimator, base, result.best, note)


def write_sweep(result: SweepResult, runner: Trials) -> Path:
    """trials.parquet (one row per gain set: its gains and mean score), flights.parquet (current
    vs best per flight) and preset.toml, in one folder renamed into place when complete; returns
    it. The folder is named after the sweep's start second: one another sweep of the estimator
    took first (two started in one second) makes it `<name>-2`, `-3`..., where the sweep that
    finished second failed on "Directory not empty" and lost its result."""
    names = [r.name for r in runner.ranges]
    trials = pa.table(
        {
            "trial": list(range(len(runner.gain_sets))),
            **{n: [g[n] for g in runner.gain_sets] for n in names},
            "score": [_mean(s) for s in runner.scores],
        }
    )
    flights = pa.Table.from_pylist(
        [
            {
                "path": layout.utf8_text(f.path),
                "vehicle": f.vehicle,
                "holdout": f.holdout,
                "current": f.current,
                "best": f.best,
            }
            for f in result.flights
        ]
    )
    preset = preset_of(result).to_toml()

    def write(tmp: Path) -> None:
        pq.write_table(trials, tmp / "trials.parquet")
        pq.write_table(flights, tmp / "flights.parquet")
        (tmp / "preset.toml").write_text(preset)

    result.folder.parent.mkdir(parents=True, exist_ok=True)
    folder, n = result.folder, 1
    while True:
        try:
            dataset.write_locked(folder, write, folder=True)
            return folder
        except OSError as exc:
            if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST):
                raise
        n += 1
        folder = result.folder.with_name(f"{result.folder.name}-{n}")
