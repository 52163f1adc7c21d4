"""/ws/live readers that time each frame twice: when the kernel put it in the reader's socket
(SO_TIMESTAMPNS) and when the reader got to it. The first is the server's doing (the loopback
hands a send over in microseconds); the second adds the reader process's own lateness, which is
the benchmark's, not the server's: 20 readers on the station's 2 cores wait for a core too.

    python -m bench.ws_readers URL N SECONDS

N clients in one process, plain sockets and a selector (no asyncio, no websockets library: the
lightest reader Python has). A frame is read exactly to its end (header, then payload), so a
`recvmsg` stops at the frame's last byte and its kernel time is the arrival of that byte. When
the reader is behind, the kernel may have merged later sends into the same buffer and given it
the later time: the kernel figure is then an upper bound on the server's part, never below it.
A frame read while more bytes were already queued is marked not exact. At the end one JSON
object: per client the (vehicle time, kernel receive, reader receive, the frame's flush: its
server_time, 1 if exact else 0) of every onboard sample, all CLOCK_MONOTONIC seconds (the
kernel's CLOCK_REALTIME stamps moved by the offset measured here), and the readers' own CPU and
run-queue wait (bench.sched).
"""

from __future__ import annotations

import base64
import json
import os
import selectors
import socket
import struct
import sys
import time
import urllib.parse

from bench.sched import thread_sched
from gcs.server import wire

#: Linux's SO_TIMESTAMPNS / SCM_TIMESTAMPNS (Python's socket module does not name them).
SO_TIMESTAMPNS = 35
_TIMESPEC = struct.Struct("@qq")
BINARY, CLOSE = 2, 8


def realtime_offset() -> float:
    """CLOCK_REALTIME − CLOCK_MONOTONIC (s), from the tightest of a few reads of both."""
    best = (float("inf"), 0.0)
    for _ in range(20):
        a = time.monotonic()
        r = time.time()
        b = time.monotonic()
        best = min(best, (b - a, r - (a + b) / 2))
    return best[1]


def kernel_time(ancillary: list[tuple[int, int, bytes]]) -> float | None:
    """The SCM_TIMESTAMPNS of a recvmsg (CLOCK_REALTIME s), None when the kernel gave none."""
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:
            seconds, nanoseconds = _TIMESPEC.unpack(data)
            return seconds + 1e-9 * nanoseconds
    return None


class Reader:
    """One WebSocket client: the handshake, then frames read to their end, each with the kernel's
    receive time of its last byte."""

    def __init__(self, url: str) -> None:
        parts = urllib.parse.urlsplit(url)
        self.sock = socket.create_connection((parts.hostname, parts.port))
        self.sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(
            f"GET {parts.path} HTTP/1.1\r\nHost: {parts.netloc}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n".encode()
        )
        head = b""
        while b"\r\n\r\n" not in head:
            head += self.sock.recv(1)  # byte by byte: what follows the headers is the first frame's
        if not head.startswith(b"HTTP/1.1 101"):
            raise ConnectionError(head.decode(errors="replace").splitlines()[0])
        self.sock.setblocking(False)
        self.buffer = b""
        self.need = 2  # bytes still missing before the next step of the frame
        self.header: tuple[int, int] | None = None  # opcode, payload length once known
        self.got: list[tuple[float, float, float, float, float]] = []
        self.closed = False

    def readable(self, offset: float) -> None:
        """Read what the socket holds, at most to the end of the current frame each time."""
        while not self.closed:
            try:
                data, ancillary, _, _ = self.sock.recvmsg(self.need - len(self.buffer), socket.CMSG_SPACE(16))
            except BlockingIOError:
                return
            if not data:
                self.closed = True
                return
            kernel = kernel_time(ancillary)
            self.buffer += data
            if len(self.buffer) == self.need:
                self._step(time.monotonic(), None if kernel is None else kernel - offset)

    def _step(self, now: float, kernel: float | None) -> None:
        if self.header is None:  # the 2-byte head, then 2 or 8 length bytes when it says so
            opcode, length = self.buffer[0] & 0x0F, self.buffer[1] & 0x7F
            extra = {126: 2, 127: 8}.get(length, 0)
            if len(self.buffer) < 2 + extra:
                self.need = 2 + extra
                return
            if extra:
                length = int.from_bytes(self.buffer[2 : 2 + extra], "big")
            self.header, self.buffer, self.need = (opcode, length), b"", length
            if length:
                return
        opcode, _ = self.header
        payload, self.buffer, self.need, self.header = self.buffer, b"", 2, None
        if opcode == CLOSE:
            self.closed = True
        elif opcode == BINARY:
            # more bytes already here: a later send may share this frame's kernel time (an upper bound)
            exact = float(kernel is not None and not self._more_queued())
            for frame in wire.decode(payload):
                if isinstance(frame, wire.PointsFrame) and "onboard" in frame.points:
                    flushed = frame.server_time
                    self.got += [(t, kernel or now, now, flushed, exact) for t in frame.points["onboard"][0]]

    def _more_queued(self) -> bool:
        try:
            return bool(self.sock.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT))
        except BlockingIOError:
            return False


def main(url: str, n: int, seconds: float) -> None:
    offset = realtime_offset()
    readers = [Reader(url) for _ in range(n)]
    selector = selectors.DefaultSelector()
    for r in readers:
        selector.register(r.sock, selectors.EVENT_READ, r)
    cpu0, sched0 = time.process_time(), thread_sched()
    end = time.monotonic() + seconds
    while time.monotonic() < end and not all(r.closed for r in readers):
        for key, _ in selector.select(0.5):
            key.data.readable(offset)
    cpu, sched = time.process_time() - cpu0, thread_sched() - sched0
    for r in readers:
        r.sock.close()
    print(
        json.dumps(
            {
                "samples": [r.got for r in readers],
                "cpu_s": cpu,
                "run_delay_s": sched.run_delay_s,
                "clock_offset_drift_s": realtime_offset() - offset,
            }
        ),
        flush=True,
    )


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), float(sys.argv[3]))
