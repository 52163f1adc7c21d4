"""What every router is given: the running Station (as its facade), the live hub, who is asking,
and the token check.

Every dependency and every route is `async def`, so all of them run on the event loop thread,
where the Station's state lives (a plain `def` would run in Starlette's thread pool).

Every state-changing request needs the token printed at start-up, wherever the server is bound
(a page the engineer has open elsewhere can reach 127.0.0.1 too: docs/security.md). Scripts send
it as the `X-GCS-Token` header, an `Authorization: Bearer` header or a `token` query parameter;
the page gets it from the start-up URL, which trades it for an HttpOnly, SameSite=Strict cookie
(`routers/page.py`), so the token never sits in the page's address or in its scripts.
"""

from __future__ import annotations

import hashlib
import secrets
from typing import Annotated

from fastapi import Depends, HTTPException, Request, status
from starlette.requests import HTTPConnection

from gcs.runtime.events import Client
from gcs.runtime.facade import FleetFacade, StationFacade
from gcs.server.guard import OTHER_SITES
from gcs.server.live import LiveHub

TOKEN_HEADER = "X-GCS-Token"


async def get_station(conn: HTTPConnection) -> StationFacade:
    """The running Station (for HTTP routes and WebSockets alike): the vehicle a
    /api/vehicles/{sysid}/ path names, else the first vehicle."""
    sysid = conn.path_params.get("sysid")
    station: StationFacade = conn.app.state.station if sysid is None else vehicle_station(conn, sysid)
    return station


async def get_hub(conn: HTTPConnection) -> LiveHub:
    """The live store and WebSocket fan-out of this app (of the vehicle the path names)."""
    sysid = conn.path_params.get("sysid")
    if sysid is None:
        hub: LiveHub = conn.app.state.hub
        return hub
    hubs: dict[int, LiveHub] = conn.app.state.hubs
    return hubs[id(vehicle_station(conn, sysid))]


def vehicle_station(conn: HTTPConnection, sysid: int) -> StationFacade:
    """The core of vehicle `sysid` (404 if no such vehicle is heard)."""
    fleet: FleetFacade | None = conn.app.state.fleet
    station: StationFacade | None
    if fleet is not None:
        station = fleet.vehicle(sysid)
    else:  # one station: its vehicle
        station = conn.app.state.station
        if station is not None and station.snapshot.vehicle.sysid != sysid:
            station = None
    if station is None or id(station) not in conn.app.state.hubs:
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"no vehicle with sysid {sysid} (GET /api/vehicles)")
    return station


def cookie_name(conn: HTTPConnection) -> str:
    """The token cookie of this server. Browsers keep cookies per host, not per port, so two
    servers on one machine (8000, 8010) must not overwrite each other's."""
    return f"gcs_token_{conn.url.port or 80}"


def presented_token(conn: HTTPConnection) -> str | None:
    """The token a request carries: header, bearer header, the page's cookie, or the query."""
    token = conn.headers.get(TOKEN_HEADER)
    if token:
        return token
    auth = conn.headers.get("authorization", "")
    if auth.lower().startswith("bearer "):
        return auth[7:].strip()
    return page_cookie(conn) or conn.query_params.get("token")


def page_cookie(conn: HTTPConnection) -> str | None:
    """The token cookie, on the page's own requests only. Browsers send it to this port from any
    page on the same host (SameSite does not tell ports apart): a link that another loopback page
    opens in a new window, GET /api/tuning, opened the tuning session with it."""
    if conn.headers.get("sec-fetch-site") in OTHER_SITES:
        return None
    return conn.cookies.get(cookie_name(conn))


def token_matches(given: str | None, expected: str) -> bool:
    return given is not None and secrets.compare_digest(given.encode(), expected.encode())


def token_id(token: str) -> str:
    """A short, stable name for a token in the audit log (never the token itself)."""
    return hashlib.sha256(token.encode()).hexdigest()[:8]


def is_authorised(conn: HTTPConnection) -> bool:
    """Does this request carry the token that changes need?"""
    return token_matches(presented_token(conn), conn.app.state.token)


async def get_client(request: Request) -> Client:
    """Who made a request, as the event log records it: "api:ADDRESS", with its user agent and,
    when it carried the right token, that token's id."""
    given = presented_token(request)
    return Client(
        f"api:{request.client.host if request.client else '?'}",
        user_agent=request.headers.get("user-agent"),
        token_id=token_id(given) if given is not None and token_matches(given, request.app.state.token) else None,
    )


async def require_token(request: Request) -> None:
    """Refuse (401, and an entry in the audit log) a state-changing request without the token."""
    if is_authorised(request):
        return
    station: StationFacade = request.app.state.station
    station.events.record("refused", await get_client(request), reason="token", path=request.url.path)
    raise HTTPException(
        status.HTTP_401_UNAUTHORIZED,
        detail=f"changes need the token printed at start-up: open the URL with ?token=, or send the "
        f"{TOKEN_HEADER} header",
    )


StationDep = Annotated[StationFacade, Depends(get_station)]
HubDep = Annotated[LiveHub, Depends(get_hub)]
ClientDep = Annotated[Client, Depends(get_client)]
#: For the `dependencies=[...]` of every route that changes state.
TOKEN = Depends(require_token)
