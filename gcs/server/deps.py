"""FastAPI dependencies shared by every router: the running GroundStation (injected, so routers
never import a global) and the token check for state-changing requests, used as
`@router.put(..., dependencies=[Depends(require_token)])` with `station = Depends(get_station)`.

`create_app` stores the station and the token on `app.state`. The token is None when the server
is bound to a loopback address (only this machine can reach it); otherwise every state-changing
request must carry it, as the `X-GCS-Token` header, an `Authorization: Bearer` header or a
`token` query parameter (the start-up URL `http://HOST:PORT/?token=...` gives it to the page).
"""

from __future__ import annotations

import secrets

from fastapi import HTTPException, Request, status
from starlette.requests import HTTPConnection

from gcs.runtime.station import GroundStation

TOKEN_HEADER = "X-GCS-Token"


def get_station(conn: HTTPConnection) -> GroundStation:
    """The running GroundStation (for HTTP routes and WebSockets alike)."""
    return conn.app.state.station


def presented_token(request: Request) -> str | None:
    """The token a request carries, from the header, a bearer header or the query string."""
    token = request.headers.get(TOKEN_HEADER)
    if token:
        return token
    auth = request.headers.get("authorization", "")
    if auth.lower().startswith("bearer "):
        return auth[7:].strip()
    return request.query_params.get("token")


def require_token(request: Request) -> None:
    """Reject a state-changing request without the start-up token when one is required."""
    expected: str | None = request.app.state.token
    if expected is None:
        return
    given = presented_token(request)
    if given is None or not secrets.compare_digest(given, expected):
        raise HTTPException(
            status.HTTP_401_UNAUTHORIZED,
            detail=f"this server is reachable from other machines: changes need the token printed at "
            f"start-up ({TOKEN_HEADER} header or ?token=)",
        )


def client_name(request: Request) -> str:
    """Who made a request, as recorded in the event log ("api:ADDRESS")."""
    return f"api:{request.client.host if request.client else '?'}"


def get_hub(conn: HTTPConnection):
    """The LiveHub (live store and WebSocket fan-out) of this app."""
    return conn.app.state.hub


def get_gains(conn: HTTPConnection):
    """The GainControl every gain change goes through."""
    return conn.app.state.gains
