"""A session (or a log run through the estimators) as a file people open directly.

- csv, parquet: the attitude of every source. Columns: wall_time (UNIX s; empty for logs without
  host time), t (vehicle s), source, roll_deg, pitch_deg, yaw_deg: degrees, because people read
  these files; the session's own Parquet keeps radians.
- mat: MATLAB/Octave, one struct per source with its errors against each reference, and the gain
  changes (gcs.sessions.matfile).
- mcap: Foxglove Studio / PlotJuggler: attitude per source, raw IMU, comparisons and events on
  JSON channels (gcs.sessions.mcapfile).

For a recorded session the attitude is what the live estimators produced (the `attitude` table);
for a log file (.tlog, .bin, .ulg) the estimators are run over it first. The output is written to
a temporary file beside it and renamed on success, so a failed run never clobbers a file.
"""

from __future__ import annotations

import contextlib
import errno
import math
import os
import secrets
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pcsv
import pyarrow.parquet as pq

from gcs.core.protocol import ProtocolTables
from gcs.sessions import layout
from gcs.sessions.contents import Contents, open_contents
from gcs.sessions.protocol import csv_table
from gcs.sessions.sources import ReplaySource, open_source

FORMATS = ("csv", "parquet", "mat", "mcap")
#: What `export` counts in its result, per format.
UNITS = {"csv": "rows", "parquet": "rows", "mat": "attitude rows", "mcap": "messages"}

T = TypeVar("T")


def degrees_table(table: pa.Table) -> pa.Table:
    """An attitude table (radians) as exported: wall_time, t, source, roll/pitch/yaw_deg. A wall
    time not known (NaN: a log without host time) is exported missing, an empty CSV field, where
    CSV readers took "nan" for a number."""
    deg = 180.0 / math.pi
    wall_time = table["wall_time"]
    return pa.table(
        {
            "wall_time": pc.if_else(pc.is_nan(wall_time), pa.scalar(None, wall_time.type), wall_time),
            "t": table["t"],
            "source": table["source"],
            **{f"{axis}_deg": pc.multiply(table[axis], deg) for axis in ("roll", "pitch", "yaw")},
        }
    )


def attitude_table(
    path: str | os.PathLike, decode: Callable[[str | os.PathLike], ReplaySource] = open_source
) -> pa.Table:
    """The attitude table of a session, or of a log replayed through every estimator (degrees);
    `decode` opens the log (a Workbench's cache, in a worker)."""
    return degrees_table(open_contents(path, decode).attitude)


def write_table(table: pa.Table, fmt: str, out: str | os.PathLike) -> None:
    if fmt == "csv":
        pcsv.write_csv(table, out)
    else:
        pq.write_table(table, out)


def write_contents(contents: Contents, fmt: str, out: str | os.PathLike) -> int:
    """Write `contents` in `fmt` to `out` (in place); returns what UNITS[fmt] counts."""
    if fmt == "mat":
        from gcs.sessions.matfile import write_mat  # noqa: PLC0415 - scipy.io: ~0.2 s at every replay's start

        return write_mat(contents, out)
    if fmt == "mcap":
        from gcs.sessions.mcapfile import write_mcap  # noqa: PLC0415 - only MCAP exports need it

        return write_mcap(contents, out)
    if fmt not in FORMATS:
        raise ValueError(f"format {fmt!r}: use one of {', '.join(FORMATS)}")
    table = degrees_table(contents.attitude)
    write_table(table, fmt, out)
    return table.num_rows


def export(
    path: str | os.PathLike,
    fmt: str,
    out: str | os.PathLike,
    decode: Callable[[str | os.PathLike], ReplaySource] = open_source,
) -> int:
    """Export the session or log at `path` to `out` in `fmt`; returns what UNITS[fmt] counts.
    InputError for bad input; `out` is replaced only when the whole file was written."""
    contents = open_contents(path, decode)
    return write_beside(Path(out), lambda tmp: write_contents(contents, fmt, tmp))


def write_beside(target: Path, write: Callable[[Path], T], tmp: Path | None = None) -> T:
    """write(tmp) on a temporary path beside target (same file system: the rename is atomic;
    one of its own unless given), then rename it to target; on any error target is untouched and
    tmp removed. An OSError names target, not the temporary path. tmp may be a file or a folder.
    A file a session recorded is never the target (`gcs export S --out S/attitude.parquet` replaced
    the session's own table): PermissionError."""
    if layout.is_recorded(target):
        raise PermissionError(errno.EPERM, "a file its session recorded, not replaced: write elsewhere", str(target))
    tmp = tmp or target.with_name(f".{target.name}.{os.getpid()}-{secrets.token_hex(4)}.tmp")
    try:
        result = write(tmp)
        os.replace(tmp, target)
    except OSError as exc:
        if exc.filename == str(tmp):  # name the file the user asked for, not the temporary one
            exc.filename = str(target)
        elif exc.filename is None and exc.errno and str(tmp) in str(exc.strerror):
            # pyarrow's: "Failed to open local file '.x.csv.123-ab.tmp'. Detail: [errno 13] ..."
            raise OSError(exc.errno, os.strerror(exc.errno), str(target)) from None
        raise
    finally:
        if tmp.is_dir():
            shutil.rmtree(tmp, ignore_errors=True)
        # OSError, not only FileNotFoundError: where tmp could not be made (a read-only file
        # system, a file where a folder should be) unlinking it fails too, and that error would
        # replace the one that says why.
        with contextlib.suppress(OSError):
            os.unlink(tmp)
    return result


def write_protocol_csv(tables: ProtocolTables, out: str | os.PathLike) -> int:
    """The protocol tables (per step, per-axis means, MSE) as one CSV, replacing `out` only when
    written; returns the rows written."""
    table = csv_table(tables)
    return write_beside(Path(out), lambda tmp: pcsv.write_csv(table, tmp) or table.num_rows)
