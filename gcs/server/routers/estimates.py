"""GET /api/estimates: for scripts, each source's latest attitude in degrees at its vehicle time,
and for each estimator its error statistics against the onboard attitude and the truth
(from the station's last published snapshot, encoded once per snapshot: gcs.server.estimates_body)."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response

from gcs.server.deps import StationDep
from gcs.server.estimates_body import EstimatesBodies
from gcs.server.models import EstimatesResponse

router = APIRouter(prefix="/api", tags=["estimates"])


@router.get("/estimates", response_model=EstimatesResponse)
async def get_estimates(request: Request, station: StationDep) -> Response:
    bodies: EstimatesBodies = request.app.state.estimates_bodies
    return Response(bodies.body(station), media_type="application/json")
