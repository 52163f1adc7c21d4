"""Closing sessions that a crash left open.

A recording process holds an exclusive `flock` on the session's lock file for as long as it
records; the kernel releases it when the process dies, even by `kill -9`. So a session whose
meta.json has no `end` and whose lock can be taken was abandoned: its end is the time of the
last complete tlog record, its Arrow streams become Parquet, and meta says `recovered: true`.
"""

from __future__ import annotations

import fcntl
import json
import os
import time
from pathlib import Path

from gcs.logs.logfile import InputError
from gcs.mavlink.tlog import read_tlog_records
from gcs.sessions import columnar, layout


def take_lock(folder: Path) -> int | None:
    """An fd holding the session's lock, or None when a live process holds it."""
    fd = os.open(folder / layout.LOCK, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        return None
    return fd


def release_lock(fd: int | None) -> None:
    if fd is not None:
        os.close(fd)


def last_tlog_time(path: Path) -> tuple[float | None, dict]:
    """UNIX time of the newest complete record (link bits cleared) and what the scan found.
    The newest, not the last in the file: packets we send are written when sent, received ones
    when the recorder drains the bus, so on a loaded machine a received packet stamped earlier
    can follow a sent one stamped later."""
    if not path.exists():
        return None, {"records": 0}
    records = read_tlog_records(path)
    last, count = None, 0
    for usec, _ in records:
        stamp = usec & ~3
        last, count = stamp if last is None else max(last, stamp), count + 1
    found = {"records": count, "skipped_bytes": records.skipped}
    if records.truncated_at is not None:
        found["truncated_at"] = records.truncated_at
    return (None if last is None else last / 1e6), found


def close_session(folder: Path, meta: dict, recovered: bool) -> dict:
    """Finish a session's files: Parquet tables, end time, meta; returns the updated meta."""
    tables = {table: columnar.finish_table(folder, table) for table in layout.TABLES}
    meta = dict(meta, tables=tables)
    if recovered:
        end, found = last_tlog_time(layout.session_file(folder, layout.TLOG))
        meta.update(end=end if end is not None else layout.meta_time(meta.get("start")), recovered=True, recovery=found)
    layout.write_meta(folder, meta)
    return meta


def recover_sessions(root: Path) -> list[dict]:
    """Close every abandoned session under root; returns one report per session recovered.
    A session that cannot be recovered (unwritable, damaged meta) is reported with an error and
    left as it is: nothing is deleted."""
    reports = []
    for info in layout.list_sessions(root):
        if not info.open:
            continue
        folder = Path(info.path)
        meta = layout.read_meta(folder)
        if "error" in meta:
            reports.append({"session": info.name, "error": meta["error"]})
            continue
        try:
            fd = take_lock(folder)
        except OSError as exc:
            reports.append({"session": info.name, "error": f"cannot lock {folder}: {exc}"})
            continue
        if fd is None:
            continue  # another process is recording it now
        try:
            meta = close_session(folder, meta, recovered=True)
            line = {
                "wall_time": time.time(),
                "kind": "recording",
                "client": "recorder",
                "event": "recovered",
                "end": meta["end"],
                **meta["recovery"],
            }
            with open(layout.session_file(folder, layout.EVENTS), "a+b") as fh:
                fh.seek(0, os.SEEK_END)
                cut = fh.tell() > 0 and (fh.seek(-1, os.SEEK_END), fh.read(1))[1] != b"\n"
                fh.write((("\n" if cut else "") + json.dumps(line) + "\n").encode())  # end a line the crash cut
            reports.append({"session": info.name, "end": meta["end"], **meta["recovery"]})
        except (OSError, InputError) as exc:
            reports.append({"session": info.name, "error": f"cannot recover {folder}: {exc}"})
        finally:
            release_lock(fd)
    return reports
