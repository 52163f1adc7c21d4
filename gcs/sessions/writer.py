"""The disk side of a recording: a thread that moves buffered bytes into the session's files.

The event loop (link reader, estimation) only appends to in-memory buffers under a lock, so it
never waits on the disk. Every `interval` seconds the thread swaps the buffers out and writes
them, which bounds what a `kill -9` can lose to one interval plus the write itself.

Each file is appended to with plain `os.write` and its last good length is remembered. On the
first write error (full disk, removed folder, lost permission) the file is cut back to that
length, so it ends at a complete record, recording stops, and `on_error` reports the error:
what was written stays valid and the live view keeps running. A fault while encoding a flush's
tables (a `source`) stops the recording the same way, with its reason: the thread never ends
silently while the station still reads "recording".
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from pathlib import Path

from gcs.sessions import layout

#: what `on_error` names when a flush's tables could not be encoded
TABLES = "the session's tables"


class AppendFile:
    """One append-only file whose length after each complete write is known."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        self.good = os.fstat(self.fd).st_size

    def append(self, data: bytes) -> None:
        """Write all of data, or cut the file back to its last good length and raise."""
        view = memoryview(data)
        try:
            while view:
                view = view[os.write(self.fd, view) :]
        except OSError:
            try:
                os.ftruncate(self.fd, self.good)
            except OSError:
                pass  # the reader's own damage handling still stops at the last complete record
            raise
        self.good += len(data)

    def close(self) -> None:
        os.close(self.fd)


class SessionWriter(threading.Thread):
    """Buffers per file name, flushed by this thread every `interval` s.

    `sources` are callables run at each flush (under no lock) that return {file name: bytes}
    for data that is encoded at flush time rather than appended by producers (Arrow batches).
    `on_error(exc, file name)` is called from this thread, once.
    """

    def __init__(
        self,
        folder: Path,
        interval: float,
        on_error: Callable[[Exception, str], None],
        sources: list[Callable[[], dict[str, bytes]]] | None = None,
    ) -> None:
        super().__init__(name=f"session-writer {folder.name}", daemon=True)
        self.folder = folder
        self.interval = interval
        self.on_error = on_error
        self.sources = sources or []
        self.files: dict[str, AppendFile] = {}
        self.bytes_written = 0
        self.last_flush: float | None = None  # monotonic
        self.failed: Exception | None = None
        self._lock = threading.Lock()
        self._buffers: dict[str, list[bytes]] = {}
        self._meta: dict | None = None
        self._rename: Path | None = None
        self._closing = threading.Event()
        self._flush_lock = threading.Lock()

    def append(self, name: str, data: bytes) -> None:
        """Queue data for file `name` (callable from any thread; never blocks on I/O)."""
        if self.failed is not None:
            return
        with self._lock:
            self._buffers.setdefault(name, []).append(data)

    def set_meta(self, meta: dict) -> None:
        """Replace meta.json at the next flush (atomically; see layout.write_meta)."""
        with self._lock:
            self._meta = meta

    def run(self) -> None:
        while not self._closing.wait(self.interval):
            self.flush()
        self.flush()

    def flush(self) -> None:
        """Write everything buffered so far (the thread calls this; so may `close`)."""
        with self._flush_lock:
            with self._lock:
                buffers, self._buffers = self._buffers, {}
                meta, self._meta = self._meta, None
                rename, self._rename = self._rename, None
            if self.failed is not None:
                return
            if rename is not None and not rename.exists():
                try:
                    os.replace(self.folder, rename)
                    self.folder = rename
                except OSError:
                    pass  # keep recording under the first name
            pending = {name: b"".join(parts) for name, parts in buffers.items()}
            encoding_fault: Exception | None = None
            for source in self.sources:
                try:
                    encoded = source()
                except Exception as exc:  # any fault: the raw bytes below still go to disk, then it stops
                    encoding_fault = exc
                    break
                for name, data in encoded.items():
                    pending[name] = pending.get(name, b"") + data
            for name, data in pending.items():
                if not data:
                    continue
                try:
                    if name not in self.files:
                        self.files[name] = AppendFile(self.folder / name)
                    self.files[name].append(data)
                except OSError as exc:
                    self.failed = exc
                    self.on_error(exc, name)
                    return
                self.bytes_written += len(data)
            if encoding_fault is not None:
                self.failed = encoding_fault
                self.on_error(encoding_fault, TABLES)
                return
            if meta is not None:
                try:
                    layout.write_meta(self.folder, meta)
                except OSError as exc:
                    self.failed = exc
                    self.on_error(exc, layout.META)
                    return
            self.last_flush = time.monotonic()

    def close(self) -> None:
        """Stop the thread after a last flush, and close the files."""
        self._closing.set()
        if self.is_alive():
            self.join()
        else:
            self.flush()
        for f in self.files.values():
            f.close()
        self.files.clear()

    def rename_folder(self, new: Path) -> None:
        """Move the session folder at the next flush (open descriptors stay valid on POSIX)."""
        with self._lock:
            self._rename = new
