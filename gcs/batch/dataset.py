"""The on-disk layout of a fleet dataset, and its atomic writes.

    DATASET/
      flights/flight=<id>/attitude.parquet    every source's attitude (columnar.ATTITUDE_SCHEMA)
                          comparison.parquet  whole-flight RMS / max / lag per estimator and reference
                          events.parquet      the session's events (contents.EVENTS_SCHEMA)
                          summary.parquet     the flight's facts and errors (SUMMARY_SCHEMA)
      failures/flight=<id>.parquet            one row: a log that could not be read, and why
      sweeps/<estimator>-<stamp>[-N]/         gain sweeps (gcs.batch.sweep)

A flight's folder is written under a temporary name and renamed whole, so a crash never leaves a
half-written partition; its presence is what "already in the dataset" means. A failure's file
and a sweep's folder are written the same way. A writer killed mid-write (a worker, scheduler or
sweep killed) leaves its temporary file or folder, never read: the next `gcs batch` removes
those whose writer is gone (`remove_leftovers`), never one a live run is writing, which holds a
lock on it (`writing`: flock; on NFS the kernel's lock manager keeps it across hosts, and it
dies with its process, however killed). The `flight=`
names are Hive partitions: `pyarrow.dataset` (and pandas, DuckDB, Spark) read every flight's
table as one with a `flight` column (`read_table`).
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import re
import secrets
import shutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq

from gcs.logs.logfile import InputError
from gcs.sessions import columnar, layout
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
    digest = hashlib.sha1(os.fsencode(Path(path).resolve())).hexdigest()[:8]  # any name's bytes
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


#: A partition being written is `.flight=<id>.<token>.tmp`; the one it replaces (--force) is moved
#: aside as `.flight=<id>.<token>.old`, the same token, until the new one is in. A failure's file
#: and a sweep's folder are written as `.<name>.<token>.tmp` beside their own.
WRITING, REPLACED = "tmp", "old"
#: what `scratch` names (the token: the writer's pid and 8 random hex digits, `new_token`)
SCRATCH_NAME = re.compile(rf"\..+\.\d+-[0-9a-f]{{8}}\.({WRITING}|{REPLACED})")


def new_token() -> str:
    return f"{os.getpid()}-{secrets.token_hex(4)}"


def scratch(target: Path, token: str, kind: str) -> Path:
    """The temporary name of a partition's folder, a failure's file or a sweep's folder (`kind`:
    WRITING or REPLACED)."""
    return target.with_name(f".{target.name}.{token}.{kind}")


@contextlib.contextmanager
def writing(path: Path, folder: bool = True) -> Iterator[None]:
    """Make `path` (a folder, or an empty file) and hold an exclusive lock on it until the block
    ends (after it is renamed in: the lock is the inode's), so `remove_leftovers` of another run
    leaves it alone. Should a cleaner have taken and removed it between its making and the lock,
    it is made again."""
    while True:
        if folder:
            path.mkdir()
            fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
        else:  # a data file (a failure's row): 0o666 as open() makes one; os.open's 0o777 made it executable
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            if path.exists() and os.stat(path).st_ino == os.fstat(fd).st_ino:
                yield
                return
        finally:
            os.close(fd)


def write_locked(target: Path, write: Callable[[Path], object], folder: bool) -> None:
    """write(tmp) on a scratch file or folder beside `target`, locked (`writing`), then renamed to
    target (`write_beside`): what a failure's file and a sweep's folder are written through."""
    tmp = scratch(target, new_token(), WRITING)
    with writing(tmp, folder):
        write_beside(target, write, tmp)


def write_flight(dataset: Path, flight: str, tables: dict[str, pa.Table]) -> Path:
    """Write the flight's tables into a temporary folder beside its partition, locked while it is
    written, then rename it in; an existing partition (--force) is moved aside only once the new
    one is complete. Moving aside and renaming in are one step for every writer (`swapping`):
    two runs writing one flight at once (two `gcs batch` into one dataset) each replace the other's
    partition whole, where the second found it gone or back in place midway (FileNotFoundError,
    ENOTEMPTY) and recorded the flight as failed."""
    target = flight_dir(dataset, flight)
    target.parent.mkdir(parents=True, exist_ok=True)
    token = new_token()
    tmp, old = scratch(target, token, WRITING), scratch(target, token, REPLACED)

    with contextlib.ExitStack() as swap:

        def write(folder: Path) -> None:
            for name, table in tables.items():
                pq.write_table(table, folder / f"{name}.parquet")
            swap.enter_context(swapping(target.parent))  # held until write_beside has renamed it in
            if target.exists():
                target.rename(old)

        try:
            with writing(tmp):
                write_beside(target, write, tmp)
        finally:
            shutil.rmtree(old, ignore_errors=True)
    with contextlib.suppress(FileNotFoundError):
        failure_file(dataset, flight).unlink()  # it can be read now
    return target


@contextlib.contextmanager
def swapping(folder: Path) -> Iterator[None]:
    """An exclusive lock on `folder` (flock, as `writing`) while a partition in it is swapped."""
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def remove_leftovers(dataset: Path) -> list[str]:
    """Remove the temporary files and folders whose writer is gone (killed mid-write), in
    flights/, failures/ and sweeps/: a `.tmp` nobody holds locked, an `.old` whose `.tmp` is not
    being written. Returns their names. The lock is taken before one is removed, so a writer
    never loses one it holds."""
    removed = []
    for part in (FLIGHTS, FAILURES, SWEEPS):
        root = dataset / part
        leftovers = sorted(p for p in root.iterdir() if SCRATCH_NAME.fullmatch(p.name)) if root.is_dir() else []
        for path in leftovers:
            base, _, _ = path.name.rpartition(".")
            with _unless_locked(path.with_name(f"{base}.{WRITING}")) as free:
                if free:  # an old partition goes with its writer's
                    if path.is_dir():
                        shutil.rmtree(path, ignore_errors=True)
                    else:
                        path.unlink(missing_ok=True)
                    removed.append(path.name)
    return removed


@contextlib.contextmanager
def _unless_locked(path: Path) -> Iterator[bool]:
    """True (holding its lock) when no live writer holds `path` locked or it is gone, else False."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        yield True
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        yield False
        return
    try:
        yield True
    finally:
        os.close(fd)


def write_failure(dataset: Path, flight: str, path: str, reason: str) -> None:
    table = pa.Table.from_pylist([{"path": path, "reason": reason}], schema=FAILURE_SCHEMA)
    target = failure_file(dataset, flight)
    target.parent.mkdir(parents=True, exist_ok=True)
    write_locked(target, lambda tmp: pq.write_table(table, tmp), folder=False)


def no_flights(dataset: str | os.PathLike) -> FileNotFoundError:
    missing = not Path(dataset).is_dir()
    why = "no such dataset folder (gcs batch --out makes one)" if missing else "no flights in the dataset"
    return FileNotFoundError(f"{dataset}: {why}")


def read_table(dataset: str | os.PathLike, table: str) -> pa.Table:
    """One table of every flight as a single table with a `flight` column (Hive partitions)."""
    root = Path(dataset) / FLIGHTS
    files = sorted(str(p) for p in root.glob(f"flight=*/{table}.parquet"))
    if not files:
        raise no_flights(dataset)
    parts = ds.partitioning(pa.schema([("flight", pa.string())]), flavor="hive")
    try:
        return ds.dataset(files, format="parquet", partitioning=parts, partition_base_dir=str(root)).to_table()
    except (pa.ArrowInvalid, OSError) as exc:  # a flight's file cut or damaged (its message names it)
        raise InputError(f"{dataset}: unreadable {table} table ({' '.join(str(exc).split())})") from None


@dataclass(frozen=True)
class Unreadable:
    """A flight whose file could not be read (cut, overwritten, not Parquet): left out, and why."""

    flight: str
    reason: str  # one line naming the file


@dataclass(frozen=True)
class Readable:
    """The rows of every flight whose file could be read (with a `flight` column), and the flights
    left out (one damaged file failed the whole fleet's report)."""

    table: pa.Table
    unreadable: list[Unreadable]


def _read_each(files: list[tuple[str, Path]], schema: pa.Schema, what: str) -> Readable:
    """(flight, file) pairs read one by one into `schema` (more columns are dropped), with the
    flight's name as a column; `what` names the table in a reason."""
    tables, unreadable = [], []
    for flight, path in files:
        try:
            table = columnar.read_parquet(path)
            rows = table.select(schema.names).cast(schema)
        except InputError as exc:
            unreadable.append(Unreadable(flight, str(exc)))
            continue
        except (KeyError, pa.ArrowException) as exc:  # a Parquet file of some other table
            unreadable.append(Unreadable(flight, f"{path}: not a {what} table ({' '.join(str(exc).split())})"))
            continue
        tables.append(rows.append_column("flight", pa.array([flight] * rows.num_rows, pa.string())))
    empty = schema.append(pa.field("flight", pa.string())).empty_table()
    return Readable(pa.concat_tables([empty, *tables]), unreadable)


def read_summaries(dataset: str | os.PathLike) -> Readable:
    """Every flight's summary rows, leaving out (and naming) the flights whose summary cannot be
    read. FileNotFoundError when the dataset has no flights."""
    root = Path(dataset) / FLIGHTS
    files = sorted(root.glob("flight=*/summary.parquet"))
    if not files:
        raise no_flights(dataset)
    return _read_each([(f.parent.name.removeprefix("flight="), f) for f in files], SUMMARY_SCHEMA, "summary")


def read_failures(dataset: str | os.PathLike) -> Readable:
    """Every failure row, with its `flight`, leaving out (and naming) the files that cannot be read."""
    files = sorted((Path(dataset) / FAILURES).glob("flight=*.parquet"))
    return _read_each([(f.stem.removeprefix("flight="), f) for f in files], FAILURE_SCHEMA, "failure")
