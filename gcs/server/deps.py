"""What every router is given: the running Station (as its facade), the live hub, and the token check.

Every dependency and every route is `async def`, so all of them run on the event loop thread,
where the Station's state lives (a plain `def` would run in Starlette's thread pool).

The token is None when the server is bound to a loopback address (only this machine can reach
it); otherwise every state-changing request must carry it, as the `X-GCS-Token` header, an
`Authorization: Bearer` header or a `token` query parameter (the start-up URL
`http://HOST:PORT/?token=...` gives it to the page).
"""

from __future__ import annotations

import secrets
from typing import Annotated

from fastapi import Depends, HTTPException, Request, status
from starlette.requests import HTTPConnection

from gcs.runtime.facade import StationFacade
from gcs.server.live import LiveHub

TOKEN_HEADER = "X-GCS-Token"


async def get_station(conn: HTTPConnection) -> StationFacade:
    """The running Station (for HTTP routes and WebSockets alike)."""
    station: StationFacade = conn.app.state.station
    return station


async def get_hub(conn: HTTPConnection) -> LiveHub:
    """The live store and WebSocket fan-out of this app."""
    hub: LiveHub = conn.app.state.hub
    return hub


def presented_token(request: Request) -> str | None:
    """The token a request carries, from the header, a bearer header or the query string."""
    token = request.headers.get(TOKEN_HEADER)
    if token:
        return token
    auth = request.headers.get("authorization", "")
    if auth.lower().startswith("bearer "):
        return auth[7:].strip()
    return request.query_params.get("token")


async def require_token(request: Request) -> None:
    """Reject a state-changing request without the start-up token when one is required."""
    expected: str | None = request.app.state.token
    if expected is None:
        return
    given = presented_token(request)
    if given is None or not secrets.compare_digest(given.encode(), expected.encode()):
        station: StationFacade = request.app.state.station
        station.events.record("refused", await get_client(request), reason="token", path=request.url.path)
        raise HTTPException(
            status.HTTP_401_UNAUTHORIZED,
            detail=f"this server is reachable from other machines: changes need the token printed at "
            f"start-up ({TOKEN_HEADER} header or ?token=)",
        )


async def get_client(request: Request) -> str:
    """Who made a request, as recorded in the event log ("api:ADDRESS")."""
    return f"api:{request.client.host if request.client else '?'}"


StationDep = Annotated[StationFacade, Depends(get_station)]
HubDep = Annotated[LiveHub, Depends(get_hub)]
ClientDep = Annotated[str, Depends(get_client)]
#: For the `dependencies=[...]` of every route that changes state.
TOKEN = Depends(require_token)
