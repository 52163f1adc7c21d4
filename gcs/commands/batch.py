"""`gcs batch`: every log or session of a fleet through the estimators into a Parquet dataset,
as Dask tasks (a LocalCluster here, or a cluster's scheduler by address)."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from gcs.runtime.replay import selection

if TYPE_CHECKING:
    from gcs.batch.flight import FlightResult


def add_cluster_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scheduler", metavar="ADDRESS", help="a running Dask scheduler (tcp://host:8786)")
    parser.add_argument(
        "--workers", type=int, metavar="N", help="local workers when no --scheduler (default: cores, at most 4)"
    )
    parser.add_argument("--dashboard", action="store_true", help="serve the local cluster's Dask dashboard (free port)")


def workers_error(args: argparse.Namespace) -> str | None:
    """Why --workers cannot be used, or None: a LocalCluster of no workers (or -1) runs no task
    and waited forever without a word; 0 quietly meant the default."""
    if args.workers is not None and args.workers < 1:
        return f"--workers {args.workers}: give 1 or more local workers (default: cores, at most 4)"
    return None


def cluster_error(exc: OSError, args: argparse.Namespace) -> str:
    """An OSError of a run on Dask as "what: why": the file it names, else the scheduler it lost or
    could not reach (the local cluster without --scheduler), else the output (the sweep's error
    named its --out for a scheduler it had lost)."""
    from gcs.batch.cluster import ClusterLost  # noqa: PLC0415 - Dask loads only when a batch runs

    if exc.filename:
        subject = str(exc.filename)
    elif isinstance(exc, ClusterLost | ConnectionError) or exc.errno is None:  # Dask's own OSErrors carry none
        subject = args.scheduler or "the local Dask cluster"
    else:
        subject = args.out
    return f"{subject}: {exc.strerror or exc}"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "logs", nargs="+", metavar="LOGS", help="session folders, .tlog/.bin/.log/.ulg files, folders of them, globs"
    )
    parser.add_argument("--out", required=True, metavar="DATASET", help="the dataset folder (created; added to)")
    parser.add_argument(
        "--estimator", "-e", action="append", metavar="NAME", help="only this estimator (repeatable; default all)"
    )
    parser.add_argument("--gain", "-g", action="append", default=[], metavar="[EST.]NAME=VALUE", help="override a gain")
    parser.add_argument("--force", action="store_true", help="redo flights already in the dataset")
    add_cluster_arguments(parser)


def _line(result: FlightResult) -> str:
    if not result.ok:
        return f"failed  {result.path}: {result.reason}"
    best = ", ".join(
        f"{est}/{ref} {sum(v * v for v in rms[:2]) ** 0.5 / 2**0.5:.2f}"
        for (est, ref), rms in sorted(result.rms.items())
        if ref in ("truth", "onboard")
    )
    return f"ok      {result.path}: {result.duration_s:.0f} s, {result.imu_samples} IMU; roll/pitch RMS deg {best}"


def run(args: argparse.Namespace) -> int:
    from gcs.batch.cluster import connect  # noqa: PLC0415 - Dask loads only when a batch runs
    from gcs.batch.run import find_flights, no_flight_lines, run_batch  # noqa: PLC0415

    try:
        names, gains = selection(args.estimator, args.gain)
    except (KeyError, ValueError) as exc:
        print(f"gcs batch: error: {exc.args[0] if isinstance(exc, KeyError) else exc}", file=sys.stderr)
        return 2
    if workers := workers_error(args):
        print(f"gcs batch: error: {workers}", file=sys.stderr)
        return 2
    flights, empty = find_flights(args.logs)
    for line in no_flight_lines("batch", empty):
        print(line, file=sys.stderr)
    if not flights:
        print("gcs batch: error: no flights found in " + " ".join(args.logs), file=sys.stderr)
        return 2
    try:
        with connect(args.scheduler, args.workers, args.dashboard) as client:
            outcome = run_batch(
                client, flights, args.out, names, gains, args.force, lambda r: print(_line(r), file=sys.stderr)
            )
    except OSError as exc:
        print(f"gcs batch: error: {cluster_error(exc, args)}", file=sys.stderr)
        return 2
    if outcome.removed:
        folders = ", ".join(outcome.removed)
        print(f"removed {len(outcome.removed)} temporary files and folders a killed run left in {args.out}: {folders}")
    failed = [r for r in outcome.done if not r.ok]
    written = len(outcome.done) - len(failed)
    skipped = len(outcome.skipped)
    print(f"{written} flights written, {len(failed)} failed, {skipped} already in {args.out} (--force redoes them)")
    # a fleet's damaged logs are failure rows and the run goes on; a run that wrote nothing it was
    # asked to is an error for the script that runs it (a report would follow on no data)
    return 1 if failed and not written else 0
