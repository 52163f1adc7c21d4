"""Attitude of every source (references and estimators) as CSV or Parquet.

For a recorded session this is what the live estimators produced (the `attitude` table); for a
log file (.tlog, .bin, .ulg) the estimators are run over it first. Columns: wall_time (UNIX s;
empty for logs without host time), t (vehicle s), source, roll_deg, pitch_deg, yaw_deg: degrees,
because people read these files; the session's own Parquet keeps radians.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pcsv
import pyarrow.parquet as pq

from gcs.sessions import columnar, layout
from gcs.sessions.sources import ReplaySource, open_source

FORMATS = ("csv", "parquet")


def attitude_table(
    path: str | os.PathLike, decode: Callable[[str | os.PathLike], ReplaySource] = open_source
) -> pa.Table:
    """The attitude table of a session, or of a log replayed through every estimator (degrees);
    `decode` opens the log (a Workbench's cache, in a worker)."""
    if layout.is_session(Path(path)):
        table = columnar.read_table(Path(path), "attitude")
    else:
        source = decode(path)
        rows: list[tuple] = []
        source.replay(source.new_pipeline(), lambda points: rows.extend(columnar.attitude_rows(points, math.nan)))
        table = pa.Table.from_pylist(
            [dict(zip(columnar.ATTITUDE_SCHEMA.names, r)) for r in rows], schema=columnar.ATTITUDE_SCHEMA
        )
    deg = 180.0 / math.pi
    return pa.table(
        {
            "wall_time": table["wall_time"],
            "t": table["t"],
            "source": table["source"],
            **{f"{axis}_deg": pc.multiply(table[axis], deg) for axis in ("roll", "pitch", "yaw")},
        }
    )


def write_table(table: pa.Table, fmt: str, out: str | os.PathLike) -> None:
    if fmt == "csv":
        pcsv.write_csv(table, out)
    else:
        pq.write_table(table, out)
