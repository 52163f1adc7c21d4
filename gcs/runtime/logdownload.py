"""Download the vehicle's onboard logs over the live link (the rules: gcs.mavlink.logtransfer).

The file is written beside its target while it comes in: NAME.partial holds the bytes at their
offsets and NAME.partial.json which chunks are in (saved every `save_interval`), so a download
cut by a link drop resumes where it stopped on the next run. When every chunk is in, the log is
written whole to NAME (gcs.sessions.export.write_beside: a temporary file renamed; NAME-2.bin, ...
when another log is already there) and the partial files are removed. Progress (bytes, rate,
re-requests) is a frozen snapshot, for the CLI and the API.
"""

from __future__ import annotations

import asyncio
import base64
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from gcs.mavlink.dialect import mavlink
from gcs.mavlink.logtransfer import LOG_DATA_LEN, LogEntry, LogListing, LogTransfer
from gcs.runtime.bus import Message
from gcs.runtime.link import Link
from gcs.sessions.export import write_beside

#: Give up when nothing arrives for this long (s) though we keep asking: the link is gone.
STALL_TIMEOUT = 10.0


class LogDownloadError(Exception):
    """A listing or download that cannot finish; the message says why (and what was kept)."""


@dataclass(frozen=True, slots=True)
class LogDownloadProgress:
    """One download as a person follows it. rate_bps: bytes per second received this run."""

    state: str  # idle | listing | downloading | done | failed
    log_id: int | None = None
    size: int = 0
    bytes_received: int = 0
    resumed_bytes: int = 0
    rate_bps: float = 0.0
    elapsed_s: float = 0.0
    requests: int = 0
    re_requests: int = 0
    path: str | None = None
    error: str | None = None

    @property
    def fraction(self) -> float:
        return self.bytes_received / self.size if self.size else 0.0


IDLE = LogDownloadProgress("idle")


def log_file_name(entry: LogEntry) -> str:
    """log3-20260101-000000.bin (the log's UTC start), or log3.bin when the vehicle has no time."""
    if entry.time_utc:
        return f"log{entry.id}-{time.strftime('%Y%m%d-%H%M%S', time.gmtime(entry.time_utc))}.bin"
    return f"log{entry.id}.bin"


class LogDownloader:
    """Lists and downloads logs over `link` (connected); one operation at a time."""

    def __init__(
        self, link: Link, idle_timeout: float = 0.5, stall_timeout: float = STALL_TIMEOUT, save_interval: float = 1.0
    ) -> None:
        self.link = link
        self.idle_timeout, self.stall_timeout, self.save_interval = idle_timeout, stall_timeout, save_interval
        self.progress = IDLE
        self.entries: list[LogEntry] = []

    def fail(self, error: str) -> None:
        """Show an error of the operation around a listing or download (e.g. no such log)."""
        self.progress = replace(self.progress, state="failed", error=error)

    def _target(self) -> tuple[int, int]:
        return self.link.target_system or 1, self.link.target_component or 1

    def _from_vehicle(self, item: Message | None) -> bool:
        """Nothing, or something the vehicle sent. Another system on the link (a second ground
        station, a companion, a hostile peer) answering the same requests had its LOG_ENTRY listed
        and its LOG_DATA written into the vehicle's log."""
        return item is None or item.sysid == self.link.target_system

    async def list_logs(self, timeout: float = 10.0) -> list[LogEntry]:
        """Every log the vehicle has (LOG_REQUEST_LIST, then the entries missed, one by one)."""
        self.progress = LogDownloadProgress("listing")
        sub = self.link.bus.subscribe("log-list", types=["LOG_ENTRY", "STATUSTEXT"], maxlen=1000)
        listing = LogListing()
        try:
            deadline = time.monotonic() + timeout
            self.link.send(mavlink.MAVLink_log_request_list_message(*self._target(), 0, 0xFFFF))
            while not listing.complete:
                item = await sub.get(timeout=min(1.0, max(deadline - time.monotonic(), 0.0)))
                if not self._from_vehicle(item):
                    if time.monotonic() < deadline:
                        continue
                    item = None
                if item is None:
                    if time.monotonic() >= deadline:
                        raise LogDownloadError(f"no complete log list from the vehicle within {timeout:g} s")
                    for log_id in listing.missing()[:1] or [0]:  # ask again: a lost entry, or all
                        start, end = (log_id, log_id) if log_id else (0, 0xFFFF)
                        self.link.send(mavlink.MAVLink_log_request_list_message(*self._target(), start, end))
                    continue
                _check_refusal(item)
                if item.type == "LOG_ENTRY":
                    m = item.msg
                    listing.add(LogEntry(m.id, m.num_logs, m.last_log_num, m.time_utc, m.size))
        except LogDownloadError as exc:
            self.progress = LogDownloadProgress("failed", error=str(exc))
            raise
        finally:
            sub.close()
        self.entries = listing.sorted()
        self.progress = IDLE
        return self.entries

    async def download(
        self, entry: LogEntry, out_dir: Path, on_progress: Callable[[LogDownloadProgress], None] | None = None
    ) -> Path:
        """Fetch log `entry` into out_dir (resuming a partial download kept there); its path."""
        out_dir.mkdir(parents=True, exist_ok=True)
        target = out_dir / log_file_name(entry)
        partial = PartialLog(target, entry)
        transfer = partial.load(self.idle_timeout)
        resumed = transfer.bytes_received
        started = time.monotonic()
        progress = LogDownloadProgress("downloading", entry.id, entry.size, resumed, resumed, path=str(target))
        self.progress = progress
        sub = self.link.bus.subscribe("log-data", types=["LOG_DATA", "STATUSTEXT"], maxlen=50_000)
        last_data = last_save = time.monotonic()
        try:
            while not transfer.complete:
                now = time.monotonic()
                request = transfer.next_request(now)
                if request is not None:
                    self.link.send(
                        mavlink.MAVLink_log_request_data_message(
                            *self._target(), request.log_id, request.ofs, request.count
                        )
                    )
                item = await sub.get(timeout=self.idle_timeout / 2)
                item = item if self._from_vehicle(item) else None
                now = time.monotonic()
                if item is not None:
                    _check_refusal(item)
                    if item.type == "LOG_DATA":
                        m = item.msg
                        if transfer.on_data(m.id, m.ofs, m.count, bytes(m.data), now):
                            last_data = now
                elif now - last_data > self.stall_timeout:
                    partial.save(bytes(transfer.data), bytes(transfer.have))
                    raise LogDownloadError(
                        f"nothing from the vehicle for {self.stall_timeout:g} s: link lost; "
                        f"{transfer.bytes_received} of {entry.size} bytes kept in {partial.data_path.name}, "
                        "run again to resume"
                    )
                if now - last_save >= self.save_interval or transfer.complete:
                    last_save = now
                    progress = _progress(progress, transfer, resumed, now - started)
                    self.progress = progress
                    if on_progress is not None:
                        on_progress(progress)
                    if not transfer.complete:
                        await asyncio.to_thread(partial.save, bytes(transfer.data), bytes(transfer.have))
            target = await asyncio.to_thread(partial.finish, transfer)
        except LogDownloadError as exc:
            self.progress = replace(_progress(progress, transfer, resumed, time.monotonic() - started), state="failed")
            self.progress = replace(self.progress, error=str(exc))
            raise
        finally:
            sub.close()
            self.link.send(mavlink.MAVLink_log_request_end_message(*self._target()))
        done = _progress(progress, transfer, resumed, time.monotonic() - started)
        self.progress = replace(done, state="done", path=str(target))
        if on_progress is not None:
            on_progress(self.progress)
        return target


def _progress(
    progress: LogDownloadProgress, transfer: LogTransfer, resumed: int, elapsed: float
) -> LogDownloadProgress:
    got = transfer.bytes_received
    return replace(
        progress,
        bytes_received=got,
        rate_bps=round((got - resumed) / elapsed, 1) if elapsed > 0 else 0.0,
        elapsed_s=round(elapsed, 3),
        requests=transfer.requests,
        re_requests=transfer.re_requests,
    )


def _check_refusal(item) -> None:
    """ArduPilot's "Disarm for log download" ends the operation ("Log download in progress" only
    says a repeated request was ignored)."""
    if item.type == "STATUSTEXT" and "disarm for log download" in str(item.msg.text).lower():
        raise LogDownloadError(f"the vehicle says: {item.msg.text}")


class PartialLog:
    """NAME.partial (the bytes at their offsets) and NAME.partial.json (the log's identity and
    which chunks are in), beside the target."""

    def __init__(self, target: Path, entry: LogEntry) -> None:
        self.target, self.entry = target, entry
        self.data_path = target.with_name(target.name + ".partial")
        self.progress_path = target.with_name(target.name + ".partial.json")

    def _identity(self) -> dict[str, int]:
        e = self.entry
        return {"id": e.id, "size": e.size, "time_utc": e.time_utc, "chunk": LOG_DATA_LEN}

    def load(self, idle_timeout: float) -> LogTransfer:
        """The transfer resumed from the partial files when they are of this very log, else new."""
        try:
            saved = json.loads(self.progress_path.read_text())
            data = bytearray(self.data_path.read_bytes())
            if saved.get("log") == self._identity() and len(data) == self.entry.size:
                have = bytearray(base64.b64decode(saved["have"]))
                return LogTransfer(self.entry, have, data, idle_timeout=idle_timeout)
        except (OSError, ValueError, KeyError, TypeError):
            pass  # none, or of another log, or damaged: start afresh
        return LogTransfer(self.entry, idle_timeout=idle_timeout)

    def save(self, data: bytes, have: bytes) -> None:
        """The bytes first, then the record of which are in (so the record never claims more);
        copies taken on the loop, written in a thread."""
        self.data_path.write_bytes(data)
        record = {"log": self._identity(), "have": base64.b64encode(have).decode()}
        write_beside(self.progress_path, lambda tmp: tmp.write_text(json.dumps(record)))

    def finish(self, transfer: LogTransfer) -> Path:
        """The whole log written, the partial files removed; the path it was written to."""
        target = free_name(self.target, bytes(transfer.data))
        write_beside(target, lambda tmp: tmp.write_bytes(transfer.data))
        for path in (self.data_path, self.progress_path):
            path.unlink(missing_ok=True)
        return target


def free_name(target: Path, data: bytes) -> Path:
    """target, or when another log is already there, the first of NAME-2.bin, NAME-3.bin, ...
    that is free or holds these very bytes. A vehicle without a clock names its logs by id alone
    (log1.bin) and the ids start again at 1 once its logs are erased: the next day's log 1
    replaced the earlier flight's file."""
    candidate, n = target, 1
    while candidate.exists() and not (candidate.is_file() and candidate.read_bytes() == data):
        n += 1
        candidate = target.with_name(f"{target.stem}-{n}{target.suffix}")
    return candidate
