"""`gcs sweep`: search one estimator's gains over many flights (scipy's differential evolution,
trials as Dask tasks); prints the best gains overall and per vehicle, best vs current per flight,
and writes the sweep and a preset file (`gcs estimate --preset-file`) into the dataset."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from gcs.batch.objective import OBJECTIVES, parse_range
from gcs.commands.batch import add_cluster_arguments, cluster_error, workers_error
from gcs.core.gains import GainError

if TYPE_CHECKING:
    from gcs.batch.sweep import SweepResult


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "logs", nargs="+", metavar="LOGS", help="the flights to tune on (files, sessions, folders, globs)"
    )
    parser.add_argument("--estimator", "-e", required=True, metavar="NAME", help="the estimator to tune")
    parser.add_argument(
        "--gain", "-g", action="append", required=True, metavar="NAME=LOW:HIGH", help="a gain to search (repeatable)"
    )
    parser.add_argument("--trials", type=int, default=40, metavar="N", help="gain sets to try (default 40)")
    parser.add_argument(
        "--objective",
        choices=list(OBJECTIVES),
        default="rms_vs_onboard",
        help="what a trial minimises: RMS error against the simulator's truth or the autopilot's own attitude "
        "(default rms_vs_onboard)",
    )
    parser.add_argument(
        "--holdout", action="append", default=[], metavar="LOGS", help="flights kept out of the search, scored after"
    )
    parser.add_argument("--seed", type=int, default=0, help="the optimiser's seed (same seed, same trials)")
    parser.add_argument("--out", required=True, metavar="DATASET", help="the dataset folder the sweep is written into")
    add_cluster_arguments(parser)


def report(result: SweepResult) -> list[str]:
    gains = ", ".join(f"{k}={v:.4g}" for k, v in result.best.items())
    score = f"{result.objective} {result.best_score:.3f} deg"
    lines = [f"best {result.estimator} gains over {result.trials} trials: {gains} ({score})"]
    for vehicle, best in result.per_vehicle.items():
        lines.append(f"  best for {vehicle}: " + ", ".join(f"{k}={v:.4g}" for k, v in best.items()))
    lines.append(f"{'flight':<60}{'set':<9}{'current':>9}{'best':>9}  (deg)")
    for f in result.flights:
        lines.append(f"{f.path[-59:]:<60}{'holdout' if f.holdout else 'train':<9}{f.current:9.3f}{f.best:9.3f}")
    for holdout in (False, True) if any(f.holdout for f in result.flights) else (False,):
        lines.append(
            f"mean on {'held-out' if holdout else 'training'} flights: current {result.mean(holdout, 'current'):.3f}, "
            f"best {result.mean(holdout, 'best'):.3f} deg"
        )
    lines.append(f"wrote {result.folder} (preset: {result.folder / 'preset.toml'})")
    return lines


def run(args: argparse.Namespace) -> int:
    from gcs.batch.cluster import connect  # noqa: PLC0415 - Dask loads only when a sweep runs
    from gcs.batch.run import find_flights, no_flight_lines  # noqa: PLC0415
    from gcs.batch.sweep import sweep  # noqa: PLC0415

    try:
        ranges = [parse_range(text, args.estimator) for text in args.gain]
    except (KeyError, GainError) as exc:
        print(f"gcs sweep: error: {exc.args[0] if isinstance(exc, KeyError) else exc}", file=sys.stderr)
        return 2
    if workers := workers_error(args):
        print(f"gcs sweep: error: {workers}", file=sys.stderr)
        return 2
    holdout, empty_holdout = find_flights(args.holdout)
    found, empty = find_flights(args.logs)
    flights = [f for f in found if f not in holdout]
    for line in no_flight_lines("sweep", empty + empty_holdout):
        print(line, file=sys.stderr)
    if not flights or args.trials < 1:
        print("gcs sweep: error: no flights to tune on, or --trials < 1", file=sys.stderr)
        return 2
    try:
        with connect(args.scheduler, args.workers, args.dashboard) as client:
            result = sweep(
                client, flights, holdout, args.estimator, ranges, args.objective, args.trials, args.out, args.seed
            )
    except OSError as exc:
        print(f"gcs sweep: error: {cluster_error(exc, args)}", file=sys.stderr)
        return 2
    print("\n".join(report(result)))
    return 0
