"""What every open page polls, answered before FastAPI's routing and dependency solving:
`GET /api/status` and `GET /api/estimates` once a second (dashboard.js; a vehicle's own under
/api/vehicles/{sysid}/ on a page opened for it), `GET /api/vehicles` every 2 s (vehicles.js).

Through FastAPI such a request cost 0.12 ms of CPU on a quiet loop (0.3–0.7 ms on a busy one),
nearly all of it the router matching its routes (each /api route twice, with its per-vehicle
copy) and solving the route's dependencies, against 0.03 ms for the status body. With five pages
their requests come together and each waited for the others (docs/benchmarks.md, branch
`tail2`). Each on a new connection at 1000 msg/s (2026-12-04, tenth session): the estimates cost
0.5–0.6 ms and the vehicle list 0.43–0.53 ms through the router, 0.20 and 0.23 ms answered here,
as the status is (0.20–0.23 ms).
This middleware sits inside the request guard (Host, Origin and the security headers still
apply) and answers those paths itself, with the bytes, status and headers their routes give; the
routes stay for the OpenAPI schema and for what reaches them (a vehicle not heard: their 404).
"""

from __future__ import annotations

import re

from fastapi import HTTPException
from starlette.requests import HTTPConnection
from starlette.types import ASGIApp, Receive, Scope, Send

from gcs.server.deps import is_authorised, vehicle_station
from gcs.server.json_body import encode
from gcs.server.vehicles import vehicle_summaries

#: a vehicle's own status and estimates (the page opened with ?vehicle=N polls these)
VEHICLE_POLL = re.compile(r"/api/vehicles/([0-9]+)(/status|/estimates)")


def answer(scope: Scope) -> bytes | None:
    """The JSON body of a polled path, None for any other (and for a vehicle not heard: the
    router then answers it, with its 404)."""
    state, path = scope["app"].state, scope["path"]
    if path == "/api/vehicles":
        return encode([v.model_dump(mode="json") for v in vehicle_summaries(state)])
    station, hub = state.station, state.hub
    vehicle = VEHICLE_POLL.fullmatch(path)
    if vehicle is not None:
        try:
            station = vehicle_station(HTTPConnection(scope), int(vehicle[1]))
        except HTTPException:
            return None
        hub, path = state.hubs[id(station)], "/api" + vehicle[2]
    if path == "/api/status":
        return state.status_bodies.body(station, hub, state.viser_port, is_authorised(HTTPConnection(scope)))
    if path == "/api/estimates":
        return state.estimates_bodies.body(station)
    return None


class PolledAnswers:
    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        body = answer(scope) if scope["type"] == "http" and scope["method"] == "GET" else None
        if body is None:
            await self.app(scope, receive, send)
            return
        await send(
            {
                "type": "http.response.start",
                "status": 200,
                "headers": [(b"content-length", str(len(body)).encode()), (b"content-type", b"application/json")],
            }
        )
        await send({"type": "http.response.body", "body": body})
