"""`gcs export`: a session (or a log run through the estimators) as CSV or Parquet (attitude of
every source, degrees), MAT (MATLAB/Octave structs) or MCAP (Foxglove Studio, PlotJuggler)."""

from __future__ import annotations

import argparse
from pathlib import Path

from gcs.commands.common import run_reporting_errors
from gcs.sessions.export import FORMATS, UNITS, export


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "session", help="a session folder (or a .tlog, .bin, .log, .ulg run through the estimators first)"
    )
    parser.add_argument(
        "--format",
        choices=FORMATS,
        default="csv",
        help="csv or parquet: one row per attitude sample of every source, degrees; mat: MATLAB/Octave structs "
        "per source, errors, gain changes; mcap: Foxglove/PlotJuggler with raw IMU, comparisons, events "
        "(default csv)",
    )
    parser.add_argument(
        "--out", help="output file, written only when the export succeeds (default: <session name>.<format> here)"
    )


def run(args: argparse.Namespace) -> int:
    out = args.out or f"{Path(args.session.rstrip('/')).stem}.{args.format}"

    def work() -> str:
        count = export(args.session, args.format, out)
        return f"{out}: {count} {UNITS[args.format]}"

    return run_reporting_errors("export", out, work, source=args.session)
