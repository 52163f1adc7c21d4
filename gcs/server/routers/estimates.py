"""GET /api/estimates: for scripts, each source's latest attitude in degrees at its vehicle time,
and for each estimator its running RMS error against the onboard attitude and the truth."""

from __future__ import annotations

import math

from fastapi import APIRouter, Depends

from gcs.runtime.station import GroundStation
from gcs.server.deps import get_station
from gcs.server.models import ErrorStats, EstimatesResponse, SourceEstimate
from gcs.server.routers.status import finite

router = APIRouter(prefix="/api", tags=["estimates"])

#: References an estimator's error is reported against.
ERROR_REFERENCES = ("onboard", "truth")


@router.get("/estimates", response_model=EstimatesResponse)
def get_estimates(station: GroundStation = Depends(get_station)) -> EstimatesResponse:
    if station.estimation is None:
        return EstimatesResponse(sources={})
    pipeline = station.estimation.pipeline
    sources = {}
    for source, p in list(pipeline.latest.items()):
        is_estimator = source in pipeline.estimators
        errors = {}
        if is_estimator:
            for ref, stats in pipeline.comparisons[source].stats.items():
                if ref in ERROR_REFERENCES:
                    s = stats.summary()
                    errors[ref] = ErrorStats(
                        n=s["n"],
                        window_rms_deg=[finite(v) for v in s["window"]["rms"]],
                        session_rms_deg=[finite(v) for v in s["session"]["rms"]],
                        session_max_deg=[finite(v) for v in s["session"]["max"]],
                    )
        sources[source] = SourceEstimate(
            source=source,
            kind="estimator" if is_estimator else "reference",
            t=p.t,
            roll_deg=math.degrees(p.roll),
            pitch_deg=math.degrees(p.pitch),
            yaw_deg=math.degrees(p.yaw),
            errors=errors,
        )
    return EstimatesResponse(sources=sources)
