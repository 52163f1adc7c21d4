"""Test protocols from the dashboard: the shipped ones, start one on the live attitudes, skip,
repeat, stop, and the run's state with every source's figures per completed step (the
dashboard's protocol panel polls GET /api/protocol). Changes need the token; the run records
its own events (gcs.runtime.protocol)."""

from __future__ import annotations

import dataclasses
import math

from fastapi import APIRouter, HTTPException, status

from gcs.core.protocol import ProtocolError
from gcs.runtime.protocol import LiveProtocol
from gcs.server.deps import TOKEN, ClientDep, StationDep
from gcs.server.models import ProtocolRun, ProtocolStart, ProtocolStatus
from gcs.sessions.protocol import available_protocols

router = APIRouter(prefix="/api/protocol", tags=["protocol"])


def run_model(live: LiveProtocol | None) -> ProtocolRun | None:
    if live is None:
        return None
    results = [
        {k: None if isinstance(v, float) and not math.isfinite(v) else v for k, v in dataclasses.asdict(m).items()}
        for m in live.completed_results()
    ]
    return ProtocolRun(state=live.state(), running=not live.ended, detect_source=live.detect_source, results=results)


@router.get("", response_model=ProtocolStatus)
async def get_protocol(station: StationDep) -> ProtocolStatus:
    return ProtocolStatus(available=available_protocols(), run=run_model(station.protocol))


@router.post(
    "/start", response_model=ProtocolStatus, dependencies=[TOKEN], responses={422: {"description": "bad protocol"}}
)
async def start_protocol(body: ProtocolStart, station: StationDep, client: ClientDep) -> ProtocolStatus:
    try:
        station.start_protocol(body.name, body.detect_source, client)
    except ProtocolError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, detail=str(exc)) from None
    return ProtocolStatus(available=available_protocols(), run=run_model(station.protocol))


@router.post(
    "/{action}", response_model=ProtocolStatus, dependencies=[TOKEN], responses={404: {"description": "no run"}}
)
async def act(action: str, station: StationDep) -> ProtocolStatus:
    live = station.protocol
    if live is None or live.ended:
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail="no protocol run in progress")
    if action == "skip":
        live.skip()
    elif action == "repeat":
        live.repeat()
    elif action == "stop":
        station.stop_protocol()
    else:
        raise HTTPException(status.HTTP_404_NOT_FOUND, detail=f"unknown action {action!r}: skip, repeat or stop")
    return ProtocolStatus(available=available_protocols(), run=run_model(live))
