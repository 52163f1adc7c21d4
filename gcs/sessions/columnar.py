"""The session's columnar tables: estimator outputs (`attitude`) and comparison snapshots
(`comparison`).

While recording, each table is an Arrow IPC *stream*: a schema, then self-delimiting record
batches appended every flush, so a file cut by a crash or a full disk is readable up to its last
complete batch. At close (or recovery) it is converted to Parquet, which is what tools read.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from gcs.logs.logfile import InputError
from gcs.sessions import layout

ATTITUDE_SCHEMA = pa.schema(
    [
        ("wall_time", pa.float64()),  # host UNIX time the point was produced, s
        ("t", pa.float64()),  # vehicle time, s since boot
        ("source", pa.string()),  # "onboard", "ahrs2", "truth" or an estimator name
        ("roll", pa.float64()),  # rad, Z-Y-X
        ("pitch", pa.float64()),
        ("yaw", pa.float64()),
    ]
)

#: One row per estimator per reference per snapshot: session RMS / max |error| in degrees.
COMPARISON_SCHEMA = pa.schema(
    [
        ("wall_time", pa.float64()),
        ("estimator", pa.string()),
        ("reference", pa.string()),
        ("n", pa.int64()),
        ("rms_roll", pa.float64()),
        ("rms_pitch", pa.float64()),
        ("rms_yaw", pa.float64()),
        ("max_roll", pa.float64()),
        ("max_pitch", pa.float64()),
        ("max_yaw", pa.float64()),
        ("lag_s", pa.float64()),
        ("imu_rate_hz", pa.float64()),
    ]
)

SCHEMAS = {"attitude": ATTITUDE_SCHEMA, "comparison": COMPARISON_SCHEMA}


def attitude_rows(points, wall_time: float) -> list[tuple]:
    """AttitudePoints (gcs.core.estimation) → attitude table rows."""
    return [(wall_time, p.t, p.source, p.roll, p.pitch, p.yaw) for p in points]


def attitude_columns(batches: list[tuple[float, list]]) -> list[Sequence]:
    """(wall time, AttitudePoints) batches → the attitude table's columns (as `attitude_rows`
    gives them, without a tuple per point: a recorder keeps the batches as they come)."""
    points = [p for _, batch in batches for p in batch]
    if not points:
        return []
    return [[wall for wall, batch in batches for _ in batch], *zip(*points)]


def warm() -> None:
    """Convert one value to Arrow now. pyarrow's first Python-to-Arrow conversion imports pandas
    when it is installed (0.7 s, holding the GIL): done by a recording's writer thread at its first
    flush, it stalled the live event loop as long (bench.loop_stalls). A recorder calls this when
    it starts, before any data."""
    pa.array([0.0], type=pa.float64())


class StreamEncoder:
    """Encodes rows of one table as Arrow IPC stream bytes; `encode(rows)` returns the bytes to
    append to the file (the schema header comes with the first call)."""

    def __init__(self, schema: pa.Schema) -> None:
        self.schema = schema
        self._sink = io.BytesIO()
        self._writer = pa.ipc.new_stream(self._sink, schema)

    def encode(self, rows: list[tuple]) -> bytes:
        return self.encode_columns(list(zip(*rows)))

    def encode_columns(self, columns: list[Sequence]) -> bytes:
        """The same for the table's columns (none: no rows)."""
        if columns:
            batch = pa.record_batch(
                [pa.array(c, type=f.type) for c, f in zip(columns, self.schema)], schema=self.schema
            )
            self._writer.write_batch(batch)
        data = self._sink.getvalue()
        self._sink.seek(0)
        self._sink.truncate()
        return data


def read_stream(path: Path, schema: pa.Schema) -> tuple[pa.Table, int | None]:
    """Every complete batch of an Arrow IPC stream file, and the byte offset where an incomplete
    or damaged tail starts (None when the file is whole)."""
    data = path.read_bytes() if path.exists() else b""
    batches: list[pa.RecordBatch] = []
    if not data:
        return schema.empty_table(), None
    buf = pa.BufferReader(data)
    try:
        reader = pa.ipc.open_stream(buf)
    except pa.ArrowInvalid:
        return schema.empty_table(), 0
    damage = None
    while True:
        good = buf.tell()
        try:
            batches.append(reader.read_next_batch())
        except StopIteration:
            break
        except (pa.ArrowInvalid, OSError):
            damage = good
            break
    if damage is None and buf.tell() < len(data):
        damage = buf.tell()
    return pa.Table.from_batches(batches, schema=schema), damage


def finish_table(folder: Path, table: str) -> dict:
    """Convert table's Arrow stream to Parquet and remove the stream; returns what happened
    (rows, and the damage offset if the stream's tail was cut)."""
    stream = layout.stream_path(folder, table)
    if not stream.exists():
        return {"rows": 0, "converted": False}
    data, damage = read_stream(stream, SCHEMAS[table])
    pq.write_table(data, layout.parquet_path(folder, table))
    stream.unlink()
    report = {"rows": data.num_rows, "converted": True}
    if damage is not None:
        report["damaged_at"] = damage
    return report


def has_table(folder: Path, table: str) -> bool:
    """Whether the session holds the table, as Parquet or as its stream."""
    return layout.parquet_path(folder, table).exists() or layout.stream_path(folder, table).exists()


def read_parquet(path: Path) -> pa.Table:
    """A Parquet file (a session's table, a fleet dataset's), or InputError naming it when it is
    cut or overwritten (a copy off a full card, an interrupted copy of a dataset)."""
    try:
        return pq.read_table(path)
    except (pa.ArrowInvalid, OSError) as exc:
        raise InputError(f"{path}: unreadable Parquet ({' '.join(str(exc).split())})") from None


def read_table(folder: Path, table: str) -> pa.Table:
    """A session's table, from Parquet if the session is closed, else from the live stream."""
    parquet = layout.parquet_path(folder, table)
    if parquet.exists():
        return read_parquet(parquet)
    return read_stream(layout.stream_path(folder, table), SCHEMAS[table])[0]
