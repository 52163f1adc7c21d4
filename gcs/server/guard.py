"""The server's front door: every HTTP request and WebSocket passes this ASGI middleware first.

- **Host** must name this server (DNS rebinding: a foreign name resolving to 127.0.0.1 gets a
  page of its own origin talking to us). Bound to loopback, only loopback names are ours; bound
  to a wildcard address any name is accepted and the token protects changes.
- **Origin**, when a browser sends one, must be this server's own (or one given with
  `--allow-origin`): another page the engineer has open cannot write, whatever it sends
  (text/plain, forms, no-cors), and cannot open the WebSocket.
- **Sec-Fetch-Site** (Fetch Metadata, which browsers send to loopback and https servers): a GET
  that another page made without an Origin header (an image, a no-cors fetch, a frame) is refused
  unless it opens a top-level document (the engineer following a link). Such a GET carried the
  engineer's cookie from another loopback port (same site, which SameSite does not tell apart) and
  spent the export and replay budget that the engineer's own page, on the same address, shares.
- **Bodies** over `MAX_BODY` are refused with 413 before they are read.
- **Headers** on every response: no framing by other pages, no content sniffing, no referrer (the
  start-up URL carries the token), and `Origin-Agent-Cluster` (see `ORIGIN_AGENT_CLUSTER`).

Each refusal is told to `on_refused` (the station's event log) with the client and the origin.
Host, Origin and Sec-Fetch-Site are decided by `FrontDoor`, which viser's port has too
(gcs.server.viser_door).
The model as a whole: docs/security.md.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

from starlette.datastructures import Headers
from starlette.responses import PlainTextResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

#: Largest request body accepted, bytes (a gain, a note, a what-if request are a few hundred).
MAX_BODY = 64 * 1024

LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")
#: Sec-Fetch-Site of a request made by a page of another origin ("same-site": another port)
OTHER_SITES = ("cross-site", "same-site")
#: The ASGI extension for answering a WebSocket handshake with an HTTP response (uvicorn has it):
#: a refused WebSocket then gets the status and the reason a refused request gets.
DENIAL_RESPONSE = "websocket.http.response"

#: `Origin-Agent-Cluster: ?1` makes Chromium give the page's origin a renderer process of its own.
#: The viser 3-D view (an iframe from the same host, another port) is same-site and would otherwise
#: share the page's main thread: with software WebGL its shader compiles and canvas read-backs
#: froze that thread for 0.3-20 s at a time on a loaded machine, and the plots waited that long.
ORIGIN_AGENT_CLUSTER = (b"origin-agent-cluster", b"?1")
SECURITY_HEADERS = [
    ORIGIN_AGENT_CLUSTER,
    (b"x-frame-options", b"DENY"),
    (b"content-security-policy", b"frame-ancestors 'none'"),
    (b"x-content-type-options", b"nosniff"),
    (b"referrer-policy", b"no-referrer"),
]


#: The one line a refused client gets, by reason.
REASONS = {
    "host": "refused: the Host header does not name this server (DNS rebinding?)",
    "origin": "refused: requests from another web page's origin are not accepted",
    "site": "refused: another web page made this request (Sec-Fetch-Site); open the dashboard itself",
    "size": f"refused: request body larger than {MAX_BODY} bytes",
}


@dataclass(frozen=True)
class Refusal:
    reason: str  # "host", "origin", "site" or "size"
    client: str  # "ADDRESS:PORT"
    origin: str | None
    host: str | None
    path: str
    user_agent: str | None


def is_loopback(host: str) -> bool:
    """True when only this machine can reach host ("localhost", 127.x, ::1)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def is_wildcard(host: str) -> bool:
    return host in ("", "0.0.0.0", "::")


def host_name(header: str) -> str:
    """The name of a Host header without its port ("[::1]:8000" → "::1")."""
    if header.startswith("["):
        return header[1 : header.find("]")] if "]" in header else header
    return header.rsplit(":", 1)[0] if header.count(":") == 1 else header


@dataclass(frozen=True)
class FrontDoor:
    """Which requests name this server and come from its own pages (Host, Origin, Sec-Fetch-Site):
    one policy for the dashboard's port (RequestGuard) and viser's (gcs.server.viser_door)."""

    bound_host: str
    allow_origins: frozenset[str] = frozenset()
    #: its page is shown in another page's frame (viser's, in the dashboard's): another page
    #: opening it in a frame is no refused request
    framed: bool = False

    @classmethod
    def of(cls, bound_host: str, allow_origins: Iterable[str] = (), framed: bool = False) -> FrontDoor:
        return cls(bound_host, frozenset(o.rstrip("/") for o in allow_origins), framed)

    def host_allowed(self, name: str) -> bool:
        if is_wildcard(self.bound_host):
            return True
        if is_loopback(self.bound_host):
            return name in LOOPBACK_NAMES or is_loopback(name)
        return name == self.bound_host or name in LOOPBACK_NAMES

    def origin_allowed(self, origin: str, host_header: str) -> bool:
        return origin in (f"http://{host_header}", f"https://{host_header}") or origin in self.allow_origins

    def refusal(self, headers: Mapping[str, str]) -> str | None:
        """Why a request with these headers is refused ("host", "origin", "site"), or None."""
        host_header = headers.get("host", "")
        origin = headers.get("origin")
        if not self.host_allowed(host_name(host_header)):
            return "host"
        if origin is not None and not self.origin_allowed(origin, host_header):
            return "origin"
        if origin is None and another_page(headers, ("document", "iframe") if self.framed else ("document",)):
            return "site"
        return None


class RequestGuard:
    def __init__(
        self,
        app: ASGIApp,
        *,
        bound_host: str,
        allow_origins: Iterable[str] = (),
        on_refused: Callable[[Refusal], None] | None = None,
    ) -> None:
        self.app = app
        self.door = FrontDoor.of(bound_host, allow_origins)
        self.on_refused = on_refused

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        host_header = headers.get("host", "")
        origin = headers.get("origin")
        reason, status = self.door.refusal(headers), 403
        if reason is None and scope["type"] == "http" and _too_long(headers):
            reason, status = "size", 413
        if reason is not None:
            self._refuse(scope, reason, origin, host_header)
            await _reject(scope, receive, send, reason, status)
            return
        if scope["type"] == "websocket":
            await self.app(scope, receive, send)
            return
        if "content-length" not in headers and scope["method"] not in ("GET", "HEAD", "OPTIONS"):
            body = await _read_chunked(receive)
            if body is None:
                self._refuse(scope, "size", origin, host_header)
                await _reject(scope, receive, send, "size", 413)
                return
            receive = _replaying(body, receive)
        await self.app(scope, receive, _with_headers(send))

    def _refuse(self, scope: Scope, reason: str, origin: str | None, host: str | None) -> None:
        if self.on_refused is not None:
            client = scope.get("client") or ("?", 0)
            agent = Headers(scope=scope).get("user-agent")
            self.on_refused(Refusal(reason, f"{client[0]}:{client[1]}", origin, host, scope.get("path", ""), agent))


def another_page(headers: Mapping[str, str], opens: tuple[str, ...] = ("document",)) -> bool:
    """A request another origin's page made, by its Fetch Metadata, other than a navigation that
    opens one of `opens` (a top-level document: a link followed). Clients that send no
    Sec-Fetch-Site (scripts, old browsers) pass."""
    if headers.get("sec-fetch-site") not in OTHER_SITES:
        return False
    return headers.get("sec-fetch-mode") != "navigate" or headers.get("sec-fetch-dest") not in opens


def _too_long(headers: Headers) -> bool:
    length = headers.get("content-length")
    try:
        return length is not None and int(length) > MAX_BODY
    except ValueError:
        return True


async def _read_chunked(receive: Receive) -> list[Message] | None:
    """The messages of a body sent without Content-Length, or None once it passes MAX_BODY."""
    messages, seen = [], 0
    while True:
        message = await receive()
        messages.append(message)
        seen += len(message.get("body", b""))
        if seen > MAX_BODY:
            return None
        if message["type"] != "http.request" or not message.get("more_body", False):
            return messages


def _replaying(messages: list[Message], receive: Receive) -> Receive:
    async def replay() -> Message:
        return messages.pop(0) if messages else await receive()

    return replay


def _with_headers(send: Send) -> Send:
    async def send_with_headers(message: Message) -> None:
        if message["type"] == "http.response.start":
            message["headers"] = [*message.get("headers", []), *SECURITY_HEADERS]
        await send(message)

    return send_with_headers


async def _reject(scope: Scope, receive: Receive, send: Send, reason: str, status: int) -> None:
    text = REASONS[reason]
    if scope["type"] == "websocket" and DENIAL_RESPONSE not in scope.get("extensions", {}):
        await send({"type": "websocket.close", "code": 1008, "reason": text})  # seen as a bare 403
        return
    response = PlainTextResponse(
        text, status_code=status, headers={k.decode(): v.decode() for k, v in SECURITY_HEADERS}
    )
    await response(scope, receive, send)
