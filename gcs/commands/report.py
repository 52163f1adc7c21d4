"""`gcs report`: a self-contained HTML flight-test report of a session or any replayable log."""

from __future__ import annotations

import argparse

from gcs.commands.common import progress_bar, run_reporting_errors
from gcs.sessions.report import write_report


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", help="a session folder, or a .tlog, .bin, .log or .ulg file")
    parser.add_argument("--out", required=True, help="the HTML file to write")


def run(args: argparse.Namespace) -> int:
    def work() -> str:
        write_report(args.path, args.out, progress_bar("report"))
        return f"wrote {args.out}"

    return run_reporting_errors("report", args.out, work, source=args.path)
