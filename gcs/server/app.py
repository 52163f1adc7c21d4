"""The FastAPI application: REST routers (every module in routers.ROUTERS), the live WebSocket,
the dashboard page and uPlot (from the package, or the checkout: `assets.web_assets`; nothing is
fetched from a CDN, so the page works with no internet)."""

from __future__ import annotations

import importlib
from typing import Any

from fastapi import FastAPI, Request, Response
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles

from gcs import __version__
from gcs.runtime.events import Client, Event
from gcs.runtime.facade import FleetFacade, StationFacade
from gcs.server.assets import web_assets
from gcs.server.colors import colors_script
from gcs.server.estimates_body import EstimatesBodies
from gcs.server.guard import Refusal, RequestGuard
from gcs.server.json_body import encode
from gcs.server.live import LiveHub
from gcs.server.polled_answers import PolledAnswers
from gcs.server.ratelimit import default_limits
from gcs.server.routers import ROUTERS
from gcs.server.status_body import StatusBodies
from gcs.server.vehicles import serve_vehicles


def create_app(
    station: StationFacade,
    hub: LiveHub | None = None,
    *,
    token: str,
    viser_port: int | None = None,
    bound_host: str = "127.0.0.1",
    allow_origins: tuple[str, ...] = (),
    fleet: FleetFacade | None = None,
) -> FastAPI:
    """The app for one running station. `token`: required on every state-changing request.
    `bound_host` and `allow_origins` set which Host and Origin
    headers the guard accepts. The hub follows the station's live estimation and events (never a replay: replays
    are computed in the worker and played by their own page). With a `fleet` (whose first vehicle
    is `station`), every /api and /ws route is also served per vehicle under
    /api/vehicles/{sysid}/ (gcs.server.vehicles), each vehicle with its own hub."""
    assets = web_assets()
    hub = hub or LiveHub()
    app = FastAPI(
        title="gcs",
        version=__version__,
        description="Live attitude of the vehicle and of the ground-side estimators; gain tuning.",
        docs_url=None,  # Swagger UI and ReDoc load their scripts from a CDN; /openapi.json stays
        redoc_url=None,
        default_response_class=StrictJSONResponse,
    )
    app.state.station = station
    app.state.hub = hub
    app.state.token = token
    app.state.assets = assets
    app.state.rate_limits = default_limits()
    app.state.viser_port = viser_port
    app.state.status_bodies = StatusBodies()
    app.state.estimates_bodies = EstimatesBodies()
    app.add_exception_handler(RequestValidationError, refuse_invalid)
    app.add_middleware(PolledAnswers)  # inside the guard: the later middleware is the outer one
    app.add_middleware(
        RequestGuard,
        bound_host=bound_host,
        allow_origins=allow_origins,
        on_refused=lambda r: record_refusal(station, r),
    )
    bodies: StatusBodies = app.state.status_bodies

    def follow_station(station: StationFacade, hub: LiveHub) -> None:
        follow(station, hub)
        station.published.connect(lambda snap: bodies.published(station, snap))

    follow_station(station, hub)
    routers = [importlib.import_module(module).router for module in ROUTERS]
    for each in routers:
        app.include_router(each)
    serve_vehicles(app, routers, fleet, hub, follow_station)
    app.add_api_route("/colors.js", colors_js, include_in_schema=False)
    app.mount("/vendor/uplot", StaticFiles(directory=assets.uplot), name="uplot")
    app.mount("/", StaticFiles(directory=assets.page, html=True), name="page")
    return app


class StrictJSONResponse(JSONResponse):
    """Every REST answer as strict JSON (gcs.core.strict_json): a non-finite number is null,
    never an invalid `NaN` token nor a 500 from Starlette's own allow_nan=False."""

    def render(self, content: Any) -> bytes:
        return encode(content)


async def refuse_invalid(request: Request, exc: Exception) -> Response:
    """422 for a body or query that fails validation, as FastAPI answers, but strict: its
    answer quotes the input, which may be NaN, Infinity or a lone surrogate (a 500 before)."""
    assert isinstance(exc, RequestValidationError)
    return StrictJSONResponse({"detail": jsonable_encoder(exc.errors())}, status_code=422)


async def colors_js() -> Response:
    return Response(colors_script(), media_type="text/javascript")


def record_refusal(station: StationFacade, refusal: Refusal) -> None:
    """Every refused request goes to the event log, with where it came from."""
    station.events.record(
        "refused",
        Client(f"api:{refusal.client}", user_agent=refusal.user_agent),
        reason=refusal.reason,
        origin=refusal.origin,
        host=refusal.host,
        path=refusal.path,
    )


def follow(station: StationFacade, hub: LiveHub) -> None:
    """The hub gets the station's live points, paced by its frame interval, and its gain changes."""
    station.points.connect(hub.on_points)
    station.pace_points(hub.flush_interval)
    station.events.recorded.connect(lambda event: forward_gain_event(hub, event))


#: Events every page hears of at once: a gain change or a reset to a preset, whichever UI made it,
#: and a new value of a vehicle parameter, whoever wrote it (a second Tuning tab learnt of another
#: page's write only at its next poll, up to 5 s later, and could write the old value back).
FORWARDED = ("gain", "preset", "param value")


def forward_gain_event(hub: LiveHub, event: Event) -> None:
    """Every page learns of the FORWARDED events, in order with the points."""
    if event.kind in FORWARDED:
        hub.broadcast({"type": event.kind, **event.as_dict()})
