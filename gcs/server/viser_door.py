"""viser's port behind the dashboard's front door (gcs.server.guard.FrontDoor).

viser's server checks neither Host nor Origin, and reads WebSocket messages of up to 50 MB, each
decoded by msgpack at once. Any web page the engineer had open could open a socket to it and read
the attitudes and gains (the guard refuses other pages that on the dashboard's port), and one
20 MB message of empty msgpack arrays became 1.3 GB of Python lists in the station's process
(RSS 0.5 → 1.8 GB, kept after), decoded under the GIL while the link's rates fell from 50 to 21 Hz.

`guarded_viser` is the context viser's server starts in (viser starts it in its own thread before
its constructor returns, as `loops_made_fast` relies on too): viser's call of websockets'
`serve` gets the door's checks before its own request handler (its page, files and socket alike)
and a message size its own page never comes near (it sends camera poses and clicks).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from http import HTTPStatus
from typing import Any

import websockets.asyncio.server
from websockets.asyncio.server import ServerConnection
from websockets.http11 import Request, Response

from gcs.server.guard import REASONS, FrontDoor, Refusal

#: Largest WebSocket message viser reads from a client, bytes.
MAX_MESSAGE = 64 * 1024


@contextmanager
def guarded_viser(door: FrontDoor, on_refused: Callable[[Refusal], None] | None = None) -> Iterator[None]:
    """Within: websockets' `serve` refuses what `door` refuses (403 and its one line, told to
    `on_refused`, called on viser's thread) and reads messages of at most MAX_MESSAGE bytes."""
    serve = websockets.asyncio.server.serve

    def guarded_serve(*args: Any, process_request: Any = None, **kwargs: Any) -> websockets.asyncio.server.serve:
        async def check(connection: ServerConnection, request: Request) -> Response | None:
            reason = door.refusal(request.headers)
            if reason is not None:
                if on_refused is not None:
                    on_refused(refusal_of(reason, connection, request))
                return connection.respond(HTTPStatus.FORBIDDEN, REASONS[reason] + "\n")
            if process_request is None:
                return None
            answer = process_request(connection, request)
            return await answer if inspect.isawaitable(answer) else answer

        return serve(*args, process_request=check, **{**kwargs, "max_size": MAX_MESSAGE})

    websockets.asyncio.server.serve = guarded_serve  # type: ignore[misc, assignment]
    try:
        yield
    finally:
        websockets.asyncio.server.serve = serve  # type: ignore[misc]


def refusal_of(reason: str, connection: ServerConnection, request: Request) -> Refusal:
    """The refusal as the event log records it: who asked, from which page, for what."""
    host, port = connection.remote_address[:2]
    origin, name, agent = (request.headers.get(h) for h in ("origin", "host", "user-agent"))
    return Refusal(reason, f"{host}:{port}", origin, name, request.path, agent)
