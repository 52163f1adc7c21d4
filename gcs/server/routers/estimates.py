"""GET /api/estimates: for scripts, each source's latest attitude in degrees at its vehicle time,
and for each estimator its error statistics against the onboard attitude and the truth
(from the station's last published snapshot)."""

from __future__ import annotations

from fastapi import APIRouter

from gcs.server.deps import StationDep
from gcs.server.models import EstimatesResponse, SourceEstimate

router = APIRouter(prefix="/api", tags=["estimates"])

#: References an estimator's error is reported against.
ERROR_REFERENCES = ("onboard", "truth")


@router.get("/estimates", response_model=EstimatesResponse)
async def get_estimates(station: StationDep) -> EstimatesResponse:
    estimation = station.snapshot.estimation
    if estimation is None:
        return EstimatesResponse(sources={})
    sources = {}
    for name, a in estimation.latest.items():
        est = estimation.estimators.get(name)
        errors = {ref: s for ref, s in est.errors.items() if ref in ERROR_REFERENCES} if est else {}
        sources[name] = SourceEstimate(
            source=name,
            kind=a.kind,
            t=a.t,
            roll_deg=a.roll_deg,
            pitch_deg=a.pitch_deg,
            yaw_deg=a.yaw_deg,
            errors=errors,
        )
    return EstimatesResponse(sources=sources)
