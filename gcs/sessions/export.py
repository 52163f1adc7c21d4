"""Attitude of every source (references and estimators) as CSV or Parquet.

For a recorded session this is what the live estimators produced (the `attitude` table); for a
log file (.tlog, .bin, .ulg) the estimators are run over it first. Columns: wall_time (UNIX s;
empty for logs without host time), t (vehicle s), source, roll_deg, pitch_deg, yaw_deg: degrees,
because people read these files; the session's own Parquet keeps radians.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pcsv
import pyarrow.parquet as pq

from gcs.sessions import columnar, layout
from gcs.sessions.sources import cached_source

FORMATS = ("csv", "parquet")


def attitude_table(path: str | os.PathLike) -> pa.Table:
    """The attitude table of a session, or of a log replayed through every estimator (degrees)."""
    if layout.is_session(Path(path)):
        table = columnar.read_table(Path(path), "attitude")
    else:
        source = cached_source(path)
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


def export_file(path: str | os.PathLike, fmt: str, out: str | os.PathLike) -> int:
    """Write the attitude table of `path` to `out` in `fmt`; returns the number of rows."""
    table = attitude_table(path)
    write_table(table, fmt, out)
    return table.num_rows
