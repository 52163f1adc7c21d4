"""Where a recorded session lives on disk and what its files are called.

A session is one folder `YYYY-MM-DD_HH-MM-SS_<vehicle>/` under the recording root. While it is
being recorded the estimator outputs are Arrow IPC streams (readable up to the last complete
batch after a crash); closing or recovering the session converts them to Parquet. `meta.json`
without an `end` marks a session still open, or left open by a crash.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import time
from dataclasses import dataclass
from pathlib import Path

from gcs.core import strict_json
from gcs.logs.logfile import InputError

TLOG = "telemetry.tlog"
EVENTS = "events.jsonl"
META = "meta.json"
LOCK = ".recording.lock"
#: table name → columns are defined in gcs.sessions.columnar
TABLES = ("attitude", "comparison")
STREAM_SUFFIX = ".arrows"
PARQUET_SUFFIX = ".parquet"

_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")
_UNLABELLED = re.compile(r"(.*_)unknown(-\d+)?")


def utf8_text(text: str) -> str:
    """text as a UTF-8 file takes it (an HTML page, a .mat, an MCAP's metadata, Parquet): a file
    name's bytes that are not UTF-8, which Python keeps as lone surrogates ("caf\\udce9.tlog") and
    every UTF-8 encoder refuses, become U+FFFD."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "replace")


def folder_name(start_wall: float, vehicle: str) -> str:
    """`YYYY-MM-DD_HH-MM-SS_<vehicle>` in local time, as people read dates at the field."""
    stamp = time.strftime("%Y-%m-%d_%H-%M-%S", time.localtime(start_wall))
    return f"{stamp}_{safe_label(vehicle)}"


def safe_label(text: str) -> str:
    """A folder-name-safe version of a vehicle label."""
    return _UNSAFE.sub("-", text).strip("-").lower() or "vehicle"


def labelled(name: str, label: str) -> str | None:
    """A session folder's name with the vehicle's label in place of the `unknown` it was started
    with before the first heartbeat (`<stamp>_unknown`, or `<stamp>_unknown-2` when another
    vehicle's session started in the same second); None when the name carries a label already."""
    match = _UNLABELLED.fullmatch(name)
    return match[1] + safe_label(label) if match else None


def unique_folder(root: Path, name: str) -> Path:
    """root/name, or root/name-2, -3 ... when a session already has that name (never overwrite)."""
    candidate, n = root / name, 2
    while candidate.exists():
        candidate, n = root / f"{name}-{n}", n + 1
    return candidate


def session_file(folder: Path, name: str) -> Path:
    """folder/name, refused (InputError) when it is a symbolic link: a session's files are its own.
    A folder copied from a stick or a colleague could link to any file on this machine, which
    replay, export or the dashboard would then read (or recovery append to), or to a device that
    never ends."""
    path = folder / name
    if path.is_symlink():
        raise InputError(f"{path}: a symbolic link inside a session folder (not followed)")
    return path


def stream_name(table: str) -> str:
    """The file name of a table's Arrow stream in a session folder."""
    return f"{table}{STREAM_SUFFIX}"


def stream_path(folder: Path, table: str) -> Path:
    return session_file(folder, stream_name(table))


def parquet_path(folder: Path, table: str) -> Path:
    return session_file(folder, f"{table}{PARQUET_SUFFIX}")


def is_session(path: Path) -> bool:
    return path.is_dir() and (path / META).is_file()


#: the files a session records (its tables as streams while open, as Parquet once closed)
RECORDED = frozenset(
    {TLOG, EVENTS, META, LOCK, *(f"{t}{suffix}" for t in TABLES for suffix in (STREAM_SUFFIX, PARQUET_SUFFIX))}
)


def is_recorded(path: Path) -> bool:
    """Whether `path` is one of the files its session folder recorded."""
    return path.name in RECORDED and is_session(path.parent)


def read_meta(folder: Path) -> dict:
    """meta.json of a session; an unreadable one is reported as such, not raised."""
    try:
        meta = json.loads(session_file(folder, META).read_text())
    except (OSError, ValueError, InputError) as exc:
        return {"error": f"{folder / META}: unreadable meta.json ({exc})"}
    if not isinstance(meta, dict):
        return {"error": f"{folder / META}: meta.json holds a {type(meta).__name__}, not an object"}
    return meta


def write_meta(folder: Path, meta: dict) -> None:
    """Replace meta.json atomically (write a temporary file, then rename), so a crash or a full
    disk leaves the previous complete version in place. A write that fails removes its temporary
    file (a full disk left a 0-byte meta.json.tmp in the session) and raises an OSError whose one
    line says so."""
    tmp = folder / (META + ".tmp")
    try:
        with open(tmp, "w") as fh:
            fh.write(strict_json.dumps(meta, indent=2, default=str))
        os.replace(tmp, folder / META)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        kept = f"{exc.strerror or exc} ({META} left as it was, its temporary file removed)"
        raise OSError(exc.errno, kept, str(folder / META)) from exc


@dataclass(frozen=True)
class SessionInfo:
    """One session as `gcs sessions` and the dashboard list it."""

    name: str
    path: str
    start: float | None
    end: float | None
    duration_s: float | None
    size_bytes: int
    vehicle: str | None
    open: bool
    recovered: bool
    #: why meta.json cannot be read, None when it can: such a session is no recording still open
    error: str | None = None

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def session_info(folder: Path) -> SessionInfo:
    meta = read_meta(folder)
    start, end = meta_time(meta.get("start")), meta_time(meta.get("end"))
    size = sum(f.lstat().st_size for f in folder.iterdir() if f.is_file() and not f.is_symlink())
    return SessionInfo(
        name=folder.name,
        path=str(folder),
        start=start,
        end=end,
        duration_s=round(end - start, 3) if start is not None and end is not None else None,
        size_bytes=size,
        vehicle=meta.get("vehicle", {}).get("label") if isinstance(meta.get("vehicle"), dict) else None,
        open=end is None,
        recovered=bool(meta.get("recovered")),
        error=meta.get("error"),
    )


def meta_time(value: object) -> float | None:
    """A UNIX time from meta.json, or None when it is missing or not a number."""
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def list_sessions(root: str | Path) -> list[SessionInfo]:
    """Every session under root, oldest first (folder names sort by start time)."""
    root = Path(root)
    if not root.is_dir():
        return []
    return [session_info(p) for p in sorted(root.iterdir()) if is_session(p)]
