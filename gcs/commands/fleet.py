"""`gcs fleet report DATASET --out FILE.html`: one page across the flights of a dataset."""

from __future__ import annotations

import argparse
import sys

from gcs.commands.common import run_reporting_errors


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    report = sub.add_parser(
        "report",
        help="one self-contained HTML page across the flights of a dataset",
        description="one self-contained HTML page across the flights of a dataset",
    )
    report.add_argument("dataset", help="a dataset written by gcs batch (and gcs sweep)")
    report.add_argument("--out", required=True, help="the HTML file to write")
    worst = "per-flight reports for the N worst flights (0: none)"
    report.add_argument("--worst", type=flight_count, default=3, metavar="N", help=worst)


def flight_count(text: str) -> int:
    """--worst's N: a negative one was taken silently (Python's slice then left out the last flights)."""
    n = int(text)
    if n < 0:
        raise argparse.ArgumentTypeError(f"{text}: give 0 or more flights")
    return n


def run(args: argparse.Namespace) -> int:
    """Exit 2 when no page could be written; 1 when it was, without the flights whose file in the
    dataset cannot be read (one line each, as `gcs batch` names its failed flights), so that a
    script publishing the page knows it is incomplete; else 0."""
    from gcs.batch.fleet_report import write_fleet_report  # noqa: PLC0415 - matplotlib, pyarrow only now

    skipped = 0

    def work() -> str:
        nonlocal skipped
        written = write_fleet_report(args.dataset, args.out, args.worst)
        for left_out in written.skipped:
            print(f"skipped {left_out.flight}: {left_out.reason}", file=sys.stderr)
        skipped = len(written.skipped)
        return f"wrote {args.out} ({written.flights} flights, {skipped} skipped)"

    code = run_reporting_errors("fleet report", args.out, work)
    return 1 if code == 0 and skipped else code
