"""The FastAPI application: REST routers (every module in routers.ROUTERS), the live WebSocket,
the dashboard page and uPlot (from the package, or the checkout: `assets.web_assets`; nothing is
fetched from a CDN, so the page works with no internet)."""

from __future__ import annotations

import importlib

from fastapi import FastAPI, Response
from fastapi.staticfiles import StaticFiles
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from gcs import __version__
from gcs.runtime.events import Event
from gcs.runtime.facade import StationFacade
from gcs.runtime.replay import ReplaySession
from gcs.server.assets import web_assets
from gcs.server.colors import colors_script
from gcs.server.live import LiveHub
from gcs.server.routers import ROUTERS


def create_app(
    station: StationFacade, hub: LiveHub | None = None, *, token: str | None = None, viser_port: int | None = None
) -> FastAPI:
    """The app for one running station. `token`: required on state-changing requests (None when
    only this machine can connect). The hub follows the station's estimation, replays and events."""
    assets = web_assets()
    hub = hub or LiveHub()
    app = FastAPI(
        title="gcs",
        version=__version__,
        description="Live attitude of the vehicle and of the ground-side estimators; gain tuning.",
    )
    app.state.station = station
    app.state.hub = hub
    app.state.token = token
    app.state.viser_port = viser_port
    app.add_middleware(OriginAgentCluster)
    station.points.connect(hub.on_points)
    station.replay_loaded.connect(lambda replay: follow_replay(hub, replay))
    station.events.recorded.connect(lambda event: forward_gain_event(hub, event))
    for module in ROUTERS:
        app.include_router(importlib.import_module(module).router)
    app.add_api_route("/colors.js", colors_js, include_in_schema=False)
    app.mount("/vendor/uplot", StaticFiles(directory=assets.uplot), name="uplot")
    app.mount("/", StaticFiles(directory=assets.page, html=True), name="page")
    return app


async def colors_js() -> Response:
    return Response(colors_script(), media_type="text/javascript")


def follow_replay(hub: LiveHub, replay: ReplaySession) -> None:
    """The dashboard plots replayed points as it plots live ones."""
    replay.points.connect(hub.on_points)


def forward_gain_event(hub: LiveHub, event: Event) -> None:
    """Every page learns of a gain change, whichever UI made it."""
    if event.kind == "gain":
        hub.broadcast({"type": "gain", **event.as_dict()})


class OriginAgentCluster:
    """ASGI middleware: `Origin-Agent-Cluster: ?1` on every HTTP response, so Chromium gives the
    page's origin a renderer process of its own. The viser 3-D view (an iframe from the same host,
    another port) is same-site and would otherwise share the page's main thread: with software
    WebGL its shader compiles and canvas read-backs froze that thread for 0.3-20 s at a time on a
    loaded machine, and the live plots' WebSocket messages waited that long."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def send_with_header(message: Message) -> None:
            if message["type"] == "http.response.start":
                message["headers"] = [*message.get("headers", []), (b"origin-agent-cluster", b"?1")]
            await send(message)

        await self.app(scope, receive, send_with_header)
