"""Vehicle parameters and remote gain tuning over REST.

GET  /api/params            the table as known now and the download progress
POST /api/params/download   start a full download (token)
GET  /api/tuning            the tuning profile: limits, current and pre-flight value of each gain
                            (opens the session with the token; without it, reads an open one)
PUT  /api/tuning/{name}     write one gain, checked against the profile and verified (token);
                            with `expected`, only if the gain still holds that value
POST /api/tuning/revert     put back every pre-flight value, verified (token)

The tuning session (pre-flight snapshot, profile detected from the table) is opened by the
first tuning request that carries the token and kept by the Station for its life, so the snapshot
always predates every write made through the panel. Opening it reads the profile's parameters
from the vehicle, so a request without the token (a read-only page, another site's <img>) does
not open it: it reads the open session, or gets a 409.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Request, status
from pydantic import Field

from gcs.mavlink.params import ParamError
from gcs.runtime.params import ParamMismatch, ParamTimeout, UnknownParam
from gcs.runtime.tuning import (
    ProfileError,
    RateLimited,
    StaleValue,
    TuningRefused,
    TuningSession,
    TuningSnapshot,
)
from gcs.server.deps import TOKEN, ClientDep, StationDep, is_authorised
from gcs.server.models import Body
from gcs.server.ratelimit import rate_limited

router = APIRouter(tags=["params"])


class TunedValue(Body):
    value: float = Field(allow_inf_nan=False)
    expected: float | None = Field(
        default=None,
        allow_inf_nan=False,
        description="the value the writer last saw; if the parameter holds another now, 412 and nothing is written",
    )


def http_error(exc: Exception) -> HTTPException:
    """The status that tells a client what to do about each failure."""
    code = (
        status.HTTP_412_PRECONDITION_FAILED
        if isinstance(exc, StaleValue)
        else status.HTTP_429_TOO_MANY_REQUESTS
        if isinstance(exc, RateLimited)
        else status.HTTP_422_UNPROCESSABLE_CONTENT
        if isinstance(exc, TuningRefused)
        else status.HTTP_409_CONFLICT
        if isinstance(exc, ParamMismatch)
        else status.HTTP_504_GATEWAY_TIMEOUT
        if isinstance(exc, ParamTimeout)
        else status.HTTP_404_NOT_FOUND
        if isinstance(exc, (UnknownParam, ProfileError))
        else status.HTTP_422_UNPROCESSABLE_CONTENT
    )
    return HTTPException(code, detail=str(exc))


async def tuning_session(station: StationDep) -> TuningSession:
    try:
        return await station.tuning()
    except (ParamError, ProfileError) as exc:
        raise http_error(exc) from None


TuningDep = Annotated[TuningSession, Depends(tuning_session)]


@router.get("/api/params")
async def get_params(station: StationDep) -> dict:
    params = station.params
    return {
        "progress": params.progress(),
        "complete": params.complete,
        "bytewise": params.bytewise,
        "params": [p.snapshot() for p in sorted(params.table.values(), key=lambda p: p.name)],
    }


@router.post(
    "/api/params/download",
    status_code=status.HTTP_202_ACCEPTED,
    dependencies=[TOKEN, Depends(rate_limited("params download"))],
)
async def start_download(station: StationDep) -> dict:
    started = station.start_param_download()
    return {"download": "started" if started else "already running", "progress": station.params.progress()}


@router.get(
    "/api/tuning",
    responses={409: {"description": "the parameter table is not downloaded, or no page with the token opened tuning"}},
)
async def get_tuning(station: StationDep, request: Request) -> TuningSnapshot:
    """The tuning session. Without the whole parameter table (POST /api/params/download first,
    which needs the token) this is a 409, not a download; without the token, a 409 until a
    request with it has opened the session (which reads the profile's parameters)."""
    if not station.params.complete:
        raise HTTPException(
            status.HTTP_409_CONFLICT, detail="parameters not downloaded yet: POST /api/params/download first"
        )
    if not is_authorised(request):
        started = station.started_tuning()
        if started is None:
            raise HTTPException(
                status.HTTP_409_CONFLICT, detail="tuning not opened yet: a page with the token opens it"
            )
        return started.snapshot()
    return (await tuning_session(station)).snapshot()


@router.put(
    "/api/tuning/{name}",
    dependencies=[TOKEN],
    responses={
        404: {"description": "unknown parameter"},
        409: {"description": "the vehicle stored another value"},
        412: {"description": "not written: the parameter no longer holds `expected`"},
        422: {"description": "refused: not in the profile, out of bounds or too large a step"},
        429: {"description": "too soon after the previous write"},
        504: {"description": "the vehicle did not answer"},
    },
)
async def put_tuned(name: str, body: TunedValue, session: TuningDep, client: ClientDep) -> dict:
    old = session.params.table[name].value if name in session.params.table else None
    try:
        stored = await session.set(name, body.value, client, body.expected)
    except ParamError as exc:
        raise http_error(exc) from None
    return {"name": name, "old": old, "new": stored.value, "verified": True, "preflight": session.preflight.get(name)}


@router.post("/api/tuning/revert", dependencies=[TOKEN])
async def revert(session: TuningDep, client: ClientDep) -> dict:
    try:
        restored = await session.revert(client)
    except ParamError as exc:
        raise http_error(exc) from None
    return {"restored": [p.snapshot() for p in restored], "params": session.rows()}
