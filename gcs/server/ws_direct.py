"""/ws/live's frames written straight to each client's socket: the WebSocket message is framed
once per flush and the same bytes go to every client, one `transport.write` each.

Why: through the ASGI `send` (Starlette's WebSocket, its exception wrapper, uvicorn's protocol,
the websockets library framing the message anew for each client) a send cost the event loop
46 µs of CPU per client per frame in `gcs serve` (26 written directly); with 5 pages at 100
frames/s that was the largest single item of its loop after the estimation and the link
(docs/benchmarks.md).

How: `DirectFrameProtocol` is uvicorn's sans-I/O WebSocket protocol offering the app an ASGI
extension (`DIRECT_WRITE` in the connection scope's "extensions", as the ASGI spec lets a
server offer what it can do beyond the spec): a function that writes one ready-made server frame
(RFC 6455 §5.2, unmasked) now and returns True, or returns False and writes nothing when the
connection cannot take it at once (not open, closing, or its transport paused by a slow
reader), and the caller sends through ASGI as before, which waits for the transport. A server
without the extension (uvicorn's own protocols) leaves every send to ASGI.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

from uvicorn.protocols.websockets.websockets_sansio_impl import WebSocketsSansIOProtocol

if TYPE_CHECKING:
    from websockets.http11 import Request

#: the ASGI scope extension's name; its value is {"write": DirectWrite}
DIRECT_WRITE = "gcs.direct_write"

#: writes one whole WebSocket frame to the client now (True), or nothing (False)
DirectWrite = Callable[[bytes], bool]

_BINARY = 0x82  # FIN + opcode 2 (binary)
_SHORT = struct.Struct("!BB")
_MEDIUM = struct.Struct("!BBH")
_LONG = struct.Struct("!BBQ")


def binary_frame(payload: bytes) -> bytes:
    """`payload` as one unfragmented, unmasked binary frame (a server's, RFC 6455 §5.2)."""
    n = len(payload)
    if n < 126:
        head = _SHORT.pack(_BINARY, n)
    elif n < 1 << 16:
        head = _MEDIUM.pack(_BINARY, 126, n)
    else:
        head = _LONG.pack(_BINARY, 127, n)
    return head + payload


def direct_write(scope: Mapping[str, Any]) -> DirectWrite | None:
    """The connection's direct write, if its server offers one."""
    offered = scope.get("extensions", {}).get(DIRECT_WRITE)
    return None if offered is None else offered["write"]


class DirectFrameProtocol(WebSocketsSansIOProtocol):
    """uvicorn's sans-I/O WebSocket protocol with the `DIRECT_WRITE` extension."""

    def handle_connect(self, event: Request) -> None:
        super().handle_connect(event)
        if self.response.status_code == 101:  # the scope exists: the app's task has not run yet
            self.scope["extensions"][DIRECT_WRITE] = {"write": self.write_frame}

    def write_frame(self, frame: bytes) -> bool:
        """Write `frame` now if the connection is open and its transport not paused; the same
        conditions uvicorn's `send` waits for or refuses on."""
        if (
            not self.handshake_complete
            or self.close_sent
            or self.disconnected
            or self.initial_response is not None
            or not self.writable.is_set()
            or self.transport.is_closing()
        ):
            return False
        self.transport.write(frame)
        return True
