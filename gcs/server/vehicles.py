"""Several vehicles on one server: GET /api/vehicles lists them, and every /api and /ws route is
served again per vehicle under /api/vehicles/{sysid}/ (/api/status → /api/vehicles/2/status,
/ws/live → /api/vehicles/2/ws/live), where `get_station` and `get_hub` (gcs.server.deps) pick
that vehicle's core and live hub. The one-vehicle URLs keep serving the first vehicle. A sysid
that is no number is a 422 with its reason, over REST and at a WebSocket's handshake alike."""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

from fastapi import APIRouter, FastAPI, HTTPException, Request, WebSocket, status
from fastapi.routing import APIRoute, APIWebSocketRoute
from starlette.convertors import Convertor, register_url_convertor
from starlette.datastructures import State
from starlette.routing import compile_path

from gcs.runtime.facade import FleetFacade, StationFacade
from gcs.server.live import LiveHub
from gcs.server.models import VehicleSummary

#: Where one vehicle's copy of the routes lives.
VEHICLE_PREFIX = "/api/vehicles/{sysid:int}"

router = APIRouter(tags=["vehicles"])


class NotANumber(Convertor[str]):
    """A path segment that is no system id: not all digits (VEHICLE_PREFIX's `int` takes those)."""

    regex = "[^/]*[^0-9/][^/]*"

    def convert(self, value: str) -> str:
        return value

    def to_string(self, value: str) -> str:
        return value


register_url_convertor("not_a_number", NotANumber())
#: Any path under /api/vehicles/ whose sysid is no number: no vehicle route matches it.
NOT_A_SYSID = "/api/vehicles/{sysid:not_a_number}/{rest:path}"


def not_a_sysid(sysid: str) -> HTTPException:
    """422, as for any other path parameter that is not what it must be, with the one line that
    says so."""
    return HTTPException(
        status.HTTP_422_UNPROCESSABLE_CONTENT,
        detail=f"sysid {sysid!r} is not a number (GET /api/vehicles lists the vehicles)",
    )


async def refuse_http(sysid: str) -> None:
    raise not_a_sysid(sysid)


async def refuse_websocket(websocket: WebSocket, sysid: str) -> None:
    """Raised before the handshake is accepted, FastAPI answers it as a WebSocket denial
    response: the client sees the 422 and the reason, as over REST, where the router's own
    refusal was a bare 403."""
    raise not_a_sysid(sysid)


@router.get("/api/vehicles", response_model=list[VehicleSummary])
async def list_vehicles(request: Request) -> list[VehicleSummary]:
    return vehicle_summaries(request.app.state)


def vehicle_summaries(state: State) -> list[VehicleSummary]:
    """Every vehicle the station hears, in the order heard (GCS and companion components are not
    vehicles); each one's routes are under its `prefix`."""
    fleet: FleetFacade | None = state.fleet
    first: StationFacade = state.station
    entries = [(e.station, e.link) for e in fleet.vehicles()] if fleet is not None else [(first, None)]
    return [summary(station, link, station is first) for station, link in entries]


def summary(station: StationFacade, link: str | None, first: bool) -> VehicleSummary:
    snap = station.snapshot
    v = snap.vehicle
    return VehicleSummary(
        sysid=v.sysid,
        compid=v.compid,
        link=link or snap.link.address,
        state=snap.link.state,
        lost_reason=snap.link.lost_reason,
        autopilot=v.autopilot,
        vehicle_type=v.vehicle_type,
        first=first,
        prefix=None if v.sysid is None else f"/api/vehicles/{v.sysid}",
    )


def serve_vehicles(
    app: FastAPI,
    routers: list[APIRouter],
    fleet: FleetFacade | None,
    hub: LiveHub,
    follow: Callable[[StationFacade, LiveHub], None],
) -> None:
    """Add /api/vehicles and the per-vehicle copy of every /api and /ws route of `routers`
    (before the page's static mount); each vehicle after the first gets its own hub,
    `follow`ed, as it is heard."""
    app.state.fleet = fleet
    app.state.hubs = {id(app.state.station): hub}

    def add(entry: Any) -> None:
        if id(entry.station) not in app.state.hubs:
            vehicle_hub = LiveHub(
                seconds=hub.seconds,
                max_rate=hub.capacity / hub.seconds,
                frame_interval=hub.frame_interval,
                client_max_frames=hub.client_max_frames,
                clock=hub.clock,
            )
            app.state.hubs[id(entry.station)] = vehicle_hub
            follow(entry.station, vehicle_hub)

    if fleet is not None:
        for entry in fleet.vehicles():
            add(entry)
        fleet.vehicle_added.connect(add)
    app.include_router(router)
    per_vehicle = APIRouter()
    for each in routers:
        for route in each.routes:
            if isinstance(route, APIRoute | APIWebSocketRoute) and route.path.startswith(("/api/", "/ws/")):
                per_vehicle.routes.append(vehicle_route(route))
    methods = ["GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"]
    per_vehicle.add_api_route(NOT_A_SYSID, refuse_http, methods=methods, include_in_schema=False)
    per_vehicle.add_api_websocket_route(NOT_A_SYSID, refuse_websocket)
    app.include_router(per_vehicle)


def vehicle_route(route: APIRoute | APIWebSocketRoute) -> APIRoute | APIWebSocketRoute:
    """The same route under VEHICLE_PREFIX (left out of the OpenAPI schema: one copy documents it)."""
    path = VEHICLE_PREFIX + route.path.removeprefix("/api")
    twin = copy.copy(route)
    twin.path = path
    twin.path_regex, twin.path_format, twin.param_convertors = compile_path(path)
    if isinstance(twin, APIRoute):
        twin.include_in_schema = False
        twin.unique_id = f"{twin.unique_id}_vehicle"
    return twin
