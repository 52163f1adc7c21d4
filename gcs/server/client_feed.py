"""One WebSocket client of the live fan-out: its encoded frames on their way, and its counters."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Coroutine
from dataclasses import dataclass, fields
from typing import Any

from gcs.runtime.dropqueue import DropOldestQueue
from gcs.server import eager
from gcs.server.ws_direct import DirectWrite, binary_frame


@dataclass(frozen=True, slots=True)
class ClientSnapshot:
    """One viewer's counters, as the status bar shows them."""

    id: int
    address: str
    sent_points: int
    sent_messages: int
    dropped_points: int
    dropped_frames: int
    queued_frames: int
    connected_s: float

    def as_dict(self) -> dict[str, int | float | str]:
        """The fields as JSON-ready values: every one is flat, so no `dataclasses.asdict` (its
        recursive copy cost each status request ~11 µs per viewer, 0.2 ms with 20)."""
        return {name: getattr(self, name) for name in CLIENT_FIELDS}


CLIENT_FIELDS = tuple(f.name for f in fields(ClientSnapshot))


#: How a feed writes one message to its client (the route's `WebSocket.send_bytes`).
Writer = Callable[[bytes], Coroutine[Any, Any, None]]


@dataclass
class ClientFeed:
    """One WebSocket client's encoded frames (`gcs.server.wire`) and its counters.

    Once it has a writer (the route attaches one), a frame offered while nothing is on its way
    to this client is written at once, in the flush's own turn: straight to the socket, already
    framed, where the server offers a direct write (`gcs.server.ws_direct`) and the socket takes
    it, else through the writer (`eager.start`: no task when the socket accepts it). While a
    send waits (a slow client: its transport paused), frames wait in the bounded queue, the
    oldest dropped and counted when it is full, and go out together as one message when the
    send is done; the flush, the link and the other clients never wait for it."""

    id: int
    address: str
    max_frames: int

    def __post_init__(self) -> None:
        self.writer: Writer | None = None
        self.direct: DirectWrite | None = None
        self.direct_writes = 0  # messages written straight to the socket (gcs.server.ws_direct)
        self.frames: DropOldestQueue[tuple[bytes, int]] = DropOldestQueue(self.max_frames)
        self.queued_points = 0
        self.sent_points = 0
        self.sent_messages = 0
        self.dropped_points = 0
        self.connected_at = time.monotonic()
        self.closed = False
        self._sending: asyncio.Task[None] | None = None

    @property
    def dropped_frames(self) -> int:
        return self.frames.dropped

    def offer(self, frame: bytes, points: int, framed: bytes | None = None) -> None:
        """Write a frame now if nothing is on its way to this client, else queue it without
        waiting; when the queue is full, the oldest frame is dropped and counted. `framed`: the
        frame as a whole WebSocket message (`ws_direct.binary_frame`), for a direct write."""
        if self.closed:
            return
        if self.writer is not None and self._sending is None and not self.frames:
            if self.direct is not None and self.direct(binary_frame(frame) if framed is None else framed):
                self.direct_writes += 1
                self.sent(points)
                return
            self._write(frame, points)
            return
        lost = self.frames.put((frame, points))
        self.queued_points += points
        if lost is not None:
            self.queued_points -= lost[1]
            self.dropped_points += lost[1]

    def attach(self, writer: Writer, direct: DirectWrite | None = None) -> None:
        """Start writing to the client: what was queued since it connected, then every frame;
        with `direct`, each frame straight to its socket whenever that takes it at once."""
        self.writer, self.direct = writer, direct
        if self.frames and self._sending is None and not self.closed:
            self._write(*self.take())

    def take(self) -> tuple[bytes, int]:
        """Everything queued as one binary message: its frames back to back (empty if none)."""
        frames = self.frames.drain()
        if len(frames) == 1:  # the usual case: a client that keeps up
            message, points = frames[0]
        else:
            message, points = b"".join(f for f, _ in frames), sum(n for _, n in frames)
        self.queued_points -= points
        return message, points

    def close(self) -> None:
        """Send nothing more (the client left, or a write to it failed)."""
        self.closed = True
        if self._sending is not None:
            self._sending.cancel()

    def _write(self, message: bytes, points: int) -> None:
        assert self.writer is not None
        try:
            task = eager.start(self.writer(message))
        except Exception:  # the client is gone: its route notices from its side and disconnects it
            self.close()
            return
        if task is None:
            self.sent(points)
            return
        self._sending = task
        task.add_done_callback(lambda done: self._written(done, points))

    def _written(self, task: asyncio.Task[None], points: int) -> None:
        self._sending = None
        if task.cancelled() or task.exception() is not None:
            self.close()
            return
        self.sent(points)
        if self.frames and not self.closed:
            self._write(*self.take())

    def sent(self, points: int) -> None:
        self.sent_points += points
        self.sent_messages += 1

    def snapshot(self) -> ClientSnapshot:
        return ClientSnapshot(
            id=self.id,
            address=self.address,
            sent_points=self.sent_points,
            sent_messages=self.sent_messages,
            dropped_points=self.dropped_points,
            dropped_frames=self.dropped_frames,
            queued_frames=len(self.frames),
            connected_s=round(time.monotonic() - self.connected_at, 1),
        )
