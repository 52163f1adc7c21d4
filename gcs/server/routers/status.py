"""GET /api/status: what the page's status bar shows — link state, rates requested vs achieved,
packet loss, how old the newest data is, estimator health and reliability, the station's parts,
the viewers. Built from the station's last published snapshot and encoded once per snapshot
(gcs.server.status_body): nothing is recomputed or re-encoded per request but its own fields."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response

from gcs.server.deps import HubDep, StationDep, is_authorised
from gcs.server.models import StatusResponse
from gcs.server.status_body import StatusBodies

router = APIRouter(prefix="/api", tags=["status"])


@router.get("/status", response_model=StatusResponse)
async def get_status(request: Request, station: StationDep, hub: HubDep) -> Response:
    bodies: StatusBodies = request.app.state.status_bodies
    body = bodies.body(station, hub, request.app.state.viser_port, is_authorised(request))
    return Response(body, media_type="application/json")
