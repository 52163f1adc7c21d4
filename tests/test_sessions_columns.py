"""The recorder hands the writer estimation points as they came, (wall time, points) batches, and
the writer makes the attitude table's columns from them: the table must be the one the rows gave."""

from __future__ import annotations

import math

import pyarrow as pa

from gcs.core.estimation import AttitudePoint
from gcs.sessions import columnar


def test_attitude_batches_encode_to_the_bytes_of_their_rows():
    batches = [
        (1700000000.25, [AttitudePoint(10.0, "dcm", 0.1, math.nan, 3.1), AttitudePoint(10.0, "kf", -0.2, 0.0, -3.1)]),
        (1700000000.5, []),
        (1700000000.75, [AttitudePoint(10.0025, "onboard", 0.0, 1e-9, math.inf)]),
    ]
    rows = [row for wall, points in batches for row in columnar.attitude_rows(points, wall)]
    by_rows = columnar.StreamEncoder(columnar.ATTITUDE_SCHEMA).encode(rows)
    by_columns = columnar.StreamEncoder(columnar.ATTITUDE_SCHEMA).encode_columns(columnar.attitude_columns(batches))
    assert by_columns == by_rows
    table = pa.ipc.open_stream(by_columns).read_all()
    assert table.column("wall_time").to_pylist() == [1700000000.25, 1700000000.25, 1700000000.75]
    assert table.column("source").to_pylist() == ["dcm", "kf", "onboard"]


def test_batches_without_points_encode_as_no_rows():
    by_rows = columnar.StreamEncoder(columnar.ATTITUDE_SCHEMA)
    by_columns = columnar.StreamEncoder(columnar.ATTITUDE_SCHEMA)
    assert by_columns.encode_columns(columnar.attitude_columns([(1.0, [])])) == by_rows.encode([])  # the schema
    assert by_columns.encode_columns(columnar.attitude_columns([])) == by_rows.encode([]) == b""
