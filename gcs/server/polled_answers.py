"""What every open page polls, answered before FastAPI's routing and dependency solving:
`GET /api/status` and `GET /api/estimates` once a second (dashboard.js), `GET /api/vehicles`
every 2 s (vehicles.js).

Through FastAPI such a request cost 0.12 ms of CPU on a quiet loop (0.3–0.7 ms on a busy one),
nearly all of it the router matching its routes (each /api route twice, with its per-vehicle
copy) and solving the route's dependencies, against 0.03 ms for the status body. With five pages
their requests come together and each waited for the others (docs/benchmarks.md, branch
`tail2`). Each on a new connection at 1000 msg/s (2026-12-04, tenth session): the estimates cost
0.5–0.6 ms and the vehicle list 0.43–0.53 ms through the router, 0.20 and 0.23 ms answered here,
as the status is (0.20–0.23 ms).
This middleware sits inside the request guard (Host, Origin and the security headers still
apply) and answers those paths itself, with the bytes, status and headers their routes give; the
routes stay for every other path that reaches them (a vehicle's /api/vehicles/{sysid}/status)
and for the OpenAPI schema.
"""

from __future__ import annotations

from collections.abc import Callable

from starlette.requests import HTTPConnection
from starlette.types import ASGIApp, Receive, Scope, Send

from gcs.server.deps import is_authorised
from gcs.server.json_body import encode
from gcs.server.vehicles import vehicle_summaries


def _status(scope: Scope) -> bytes:
    state = scope["app"].state
    authorised = is_authorised(HTTPConnection(scope))
    return state.status_bodies.body(state.station, state.hub, state.viser_port, authorised)


def _estimates(scope: Scope) -> bytes:
    state = scope["app"].state
    return state.estimates_bodies.body(state.station)


def _vehicles(scope: Scope) -> bytes:
    return encode([v.model_dump(mode="json") for v in vehicle_summaries(scope["app"].state)])


#: path -> its JSON body, for this request
ANSWERS: dict[str, Callable[[Scope], bytes]] = {
    "/api/status": _status,
    "/api/estimates": _estimates,
    "/api/vehicles": _vehicles,
}


class PolledAnswers:
    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        answer = ANSWERS.get(scope["path"]) if scope["type"] == "http" and scope["method"] == "GET" else None
        if answer is None:
            await self.app(scope, receive, send)
            return
        body = answer(scope)
        await send(
            {
                "type": "http.response.start",
                "status": 200,
                "headers": [(b"content-length", str(len(body)).encode()), (b"content-type", b"application/json")],
            }
        )
        await send({"type": "http.response.body", "body": body})
