"""`gcs export`: attitude of every source of a session (or a log run through the estimators)
as CSV or Parquet, in degrees."""

from __future__ import annotations

import argparse
from pathlib import Path

from gcs.commands.common import run_reporting_errors
from gcs.sessions.export import FORMATS, attitude_table, write_table


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("session", help="a session folder (or a .tlog, .bin, .ulg to estimate first)")
    parser.add_argument("--format", choices=FORMATS, default="csv", help="output format (default csv)")
    parser.add_argument("--out", help="output file (default: <session name>.<format> here)")


def run(args: argparse.Namespace) -> int:
    out = args.out or f"{Path(args.session.rstrip('/')).stem}.{args.format}"

    def work() -> str:
        table = attitude_table(args.session)
        write_table(table, args.format, out)
        return f"{out}: {table.num_rows} rows"

    return run_reporting_errors("export", out, work)
