"""The on-disk layout of a fleet dataset, and its atomic writes.

    DATASET/
      flights/flight=<id>/attitude.parquet    every source's attitude (columnar.ATTITUDE_SCHEMA)
                          comparison.parquet  whole-flight RMS / max / lag per estimator and reference
                          events.parquet      the session's events (contents.EVENTS_SCHEMA)
                          summary.parquet     the flight's facts and errors (SUMMARY_SCHEMA)
      failures/flight=<id>.parquet            one row: a log that could not be read, and why
      sweeps/<estimator>-<stamp>/             gain sweeps (gcs.batch.sweep)

A flight's folder is written under a temporary name and renamed whole, so a crash never leaves a
half-written partition; its presence is what "already in the dataset" means. The `flight=`
names are Hive partitions: `pyarrow.dataset` (and pandas, DuckDB, Spark) read every flight's
table as one with a `flight` column (`read_table`).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import secrets
import shutil
from pathlib import Path

import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq

from gcs.sessions import layout
from gcs.sessions.export import write_beside

FLIGHTS = "flights"
FAILURES = "failures"
SWEEPS = "sweeps"
TABLES = ("attitude", "comparison", "events", "summary")

#: One row per estimator and reference of a flight, with the flight's facts repeated: the table
#: a fleet is compared on. Errors in degrees, lag in s (positive: the estimator is late).
SUMMARY_SCHEMA = pa.schema(
    [
        ("path", pa.string()),
        ("kind", pa.string()),  # "session", "tlog", "dataflash", "ulog"
        ("vehicle", pa.string()),
        ("firmware", pa.string()),
        ("started", pa.float64()),  # UNIX s: the session's start, else the file's mtime
        ("duration_s", pa.float64()),
        ("imu_samples", pa.int64()),
        ("imu_rate_hz", pa.float64()),  # IMU samples per second of IMU time
        ("damage", pa.string()),
        ("estimator", pa.string()),
        ("reference", pa.string()),
        ("n", pa.int64()),
        *((f"rms_{a}", pa.float64()) for a in ("roll", "pitch", "yaw")),
        *((f"max_{a}", pa.float64()) for a in ("roll", "pitch", "yaw")),
        ("lag_s", pa.float64()),
        ("reliable", pa.bool_()),
    ]
)

FAILURE_SCHEMA = pa.schema([("path", pa.string()), ("reason", pa.string())])


def flight_id(path: str | os.PathLike) -> str:
    """A stable, folder-safe name for a flight: its file or folder name and a hash of its
    resolved path (two flights called telemetry.tlog in different folders stay apart)."""
    resolved = str(Path(path).resolve())
    digest = hashlib.sha1(resolved.encode()).hexdigest()[:8]
    return f"{layout.safe_label(Path(path).name)}-{digest}"


def flight_dir(dataset: Path, flight: str) -> Path:
    return dataset / FLIGHTS / f"flight={flight}"


def failure_file(dataset: Path, flight: str) -> Path:
    return dataset / FAILURES / f"flight={flight}.parquet"


def done_flights(dataset: Path) -> set[str]:
    """Flights whose partition is complete (temporary folders start with a dot)."""
    root = dataset / FLIGHTS
    if not root.is_dir():
        return set()
    return {p.name.removeprefix("flight=") for p in root.iterdir() if p.name.startswith("flight=")}


def write_flight(dataset: Path, flight: str, tables: dict[str, pa.Table]) -> Path:
    """Write the flight's tables into a temporary folder beside its partition, then rename it in;
    an existing partition (--force) is moved aside only once the new one is complete."""
    target = flight_dir(dataset, flight)
    target.parent.mkdir(parents=True, exist_ok=True)
    old = target.with_name(f".{target.name}.{os.getpid()}-{secrets.token_hex(4)}.old")

    def write(tmp: Path) -> None:
        tmp.mkdir()
        for name, table in tables.items():
            pq.write_table(table, tmp / f"{name}.parquet")
        if target.exists():
            target.rename(old)

    try:
        write_beside(target, write)
    finally:
        shutil.rmtree(old, ignore_errors=True)
    with contextlib.suppress(FileNotFoundError):
        failure_file(dataset, flight).unlink()  # it can be read now
    return target


def write_failure(dataset: Path, flight: str, path: str, reason: str) -> None:
    table = pa.Table.from_pylist([{"path": path, "reason": reason}], schema=FAILURE_SCHEMA)
    target = failure_file(dataset, flight)
    target.parent.mkdir(parents=True, exist_ok=True)
    write_beside(target, lambda tmp: pq.write_table(table, tmp))


def read_table(dataset: str | os.PathLike, table: str) -> pa.Table:
    """One table of every flight as a single table with a `flight` column (Hive partitions)."""
    root = Path(dataset) / FLIGHTS
    files = sorted(str(p) for p in root.glob(f"flight=*/{table}.parquet"))
    if not files:
        missing = not Path(dataset).is_dir()
        why = "no such dataset folder (gcs batch --out makes one)" if missing else "no flights in the dataset"
        raise FileNotFoundError(f"{dataset}: {why}")
    parts = ds.partitioning(pa.schema([("flight", pa.string())]), flavor="hive")
    return ds.dataset(files, format="parquet", partitioning=parts, partition_base_dir=str(root)).to_table()


def read_failures(dataset: str | os.PathLike) -> pa.Table:
    """Every failure row, with its `flight`."""
    files = sorted((Path(dataset) / FAILURES).glob("flight=*.parquet"))
    tables = [
        pq.read_table(f).append_column("flight", pa.array([f.stem.removeprefix("flight=")], pa.string())) for f in files
    ]
    return pa.concat_tables(tables) if tables else FAILURE_SCHEMA.append(pa.field("flight", pa.string())).empty_table()
