"""`gcs export`: attitude of every source (references and estimators) as CSV or Parquet.

For a recorded session this is what the live estimators produced (the `attitude` table); for a
log file (.tlog, .bin, .ulg) the estimators are run over it first. Columns: wall_time (UNIX s;
empty for logs without host time), t (vehicle s), source, roll_deg, pitch_deg, yaw_deg: degrees,
because people read these files; the session's own Parquet keeps radians.
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

FORMATS = ("csv", "parquet")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("session", help="a session folder (or a .tlog, .bin, .ulg to estimate first)")
    parser.add_argument("--format", choices=FORMATS, default="csv", help="output format (default csv)")
    parser.add_argument("--out", help="output file (default: <session name>.<format> here)")


def attitude_table(path: str | os.PathLike):
    """The attitude table of a session, or of a log replayed through every estimator (degrees)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    from gcs.sessions import columnar, layout
    from gcs.sessions.replay import ReplaySession
    from gcs.sessions.sources import cached_source

    if layout.is_session(Path(path)):
        table = columnar.read_table(Path(path), "attitude")
    else:
        session = ReplaySession(cached_source(path), speed=0)
        rows: list[tuple] = []
        session.add_listener(lambda points: rows.extend(columnar.attitude_rows(points, math.nan)))
        session.run_to_end()
        table = pa.Table.from_pylist([dict(zip(columnar.ATTITUDE_SCHEMA.names, r)) for r in rows],
                                     schema=columnar.ATTITUDE_SCHEMA)
    deg = 180.0 / math.pi
    return pa.table({
        "wall_time": table["wall_time"], "t": table["t"], "source": table["source"],
        **{f"{axis}_deg": pc.multiply(table[axis], deg) for axis in ("roll", "pitch", "yaw")},
    })


def write_table(table, fmt: str, out: str | os.PathLike) -> None:
    import pyarrow.csv as pcsv
    import pyarrow.parquet as pq

    if fmt == "csv":
        pcsv.write_csv(table, out)
    else:
        pq.write_table(table, out)


def run(args: argparse.Namespace) -> int:
    from gcs.sessions.command import run_reporting_errors

    out = args.out or f"{Path(args.session.rstrip('/')).stem}.{args.format}"

    def work() -> str:
        table = attitude_table(args.session)
        write_table(table, args.format, out)
        return f"{out}: {table.num_rows} rows"

    return run_reporting_errors("export", out, work)
