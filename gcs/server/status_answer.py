"""`GET /api/status` answered before FastAPI's routing and dependency solving.

Every open page polls the status once a second. Its body is the snapshot's part, encoded once per
publish (gcs.server.status_body), and a few fields of its own; through FastAPI the request cost
0.12 ms of CPU on a quiet loop (0.3–0.7 ms on a busy one), nearly all of it the router matching
~100 routes and solving the route's dependencies, against 0.03 ms for the body. With five pages
their requests come together and each waited for the others (docs/benchmarks.md, branch `tail2`).
This middleware sits inside the request guard (Host, Origin and the security headers still
apply) and answers that one path itself, with the bytes, status and headers the route gives;
the route stays for every other path that reaches it (a vehicle's /api/vehicles/{sysid}/status)
and for the OpenAPI schema.
"""

from __future__ import annotations

from starlette.requests import HTTPConnection
from starlette.types import ASGIApp, Receive, Scope, Send

from gcs.server.deps import is_authorised

PATH = "/api/status"


class StatusAnswer:
    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["path"] != PATH or scope["method"] != "GET":
            await self.app(scope, receive, send)
            return
        state = scope["app"].state
        authorised = is_authorised(HTTPConnection(scope))
        body = state.status_bodies.body(state.station, state.hub, state.viser_port, authorised)
        await send(
            {
                "type": "http.response.start",
                "status": 200,
                "headers": [(b"content-length", str(len(body)).encode()), (b"content-type", b"application/json")],
            }
        )
        await send({"type": "http.response.body", "body": body})
