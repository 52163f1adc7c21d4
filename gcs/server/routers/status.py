"""GET /api/status: what the page's status bar shows — link state, rates requested vs achieved,
packet loss, how old the newest data is, estimator health and reliability, the viewers."""

from __future__ import annotations

import math

from fastapi import APIRouter, Depends, Request

from gcs.runtime.station import GroundStation
from gcs.server.deps import get_hub, get_station
from gcs.server.live import LiveHub
from gcs.server.models import EstimatorStatus, LinkStatus, StatusResponse, StreamRate

router = APIRouter(prefix="/api", tags=["status"])


def finite(x: float | None) -> float | None:
    """JSON has no NaN: unknown numbers are null."""
    return None if x is None or not math.isfinite(x) else x


@router.get("/status", response_model=StatusResponse)
def get_status(
    request: Request, station: GroundStation = Depends(get_station), hub: LiveHub = Depends(get_hub)
) -> StatusResponse:
    link = station.link.status()
    stats = link["stats"]
    streams = station.streams.report()
    age = hub.data_age()
    return StatusResponse(
        link=LinkStatus(
            address=link["address"],
            state=link["state"],
            heartbeat_age_s=link["heartbeat_age_s"],
            packets=stats["packets"],
            packets_lost=stats["packets_lost"],
            loss_fraction=stats["loss_fraction"],
            crc_errors=stats["crc_errors"],
            malformed=stats["malformed"],
            bytes_per_s=stats["bytes_per_s"],
            rates_hz=stats["rates_hz"],
            stream_method=streams["method"],
            streams={name: StreamRate(**row) for name, row in streams["messages"].items()},
        ),
        vehicle=station.vehicle.as_dict(),
        data_age_ms=None if age is None else round(age * 1000, 1),
        imu_type=station.estimation.imu_type if station.estimation else None,
        estimators=estimator_status(station),
        clients=[c.as_dict() for c in hub.clients.values()],
        viser_port=request.app.state.viser_port,
        token_required=request.app.state.token is not None,
    )


def estimator_status(station: GroundStation) -> dict[str, EstimatorStatus]:
    if station.estimation is None:
        return {}
    pipeline = station.estimation.pipeline
    out = {}
    for name, est in pipeline.estimators.items():
        comparison = pipeline.comparisons[name]
        reliable, reason = comparison.reliability()
        out[name] = EstimatorStatus(
            preset=est.preset,
            reliable=reliable,
            reason=reason,
            imu_rate_hz=round(comparison.imu_rate(), 2),
            lag_s=comparison.lag(),
            health={k: finite(v) if isinstance(v, float) else v for k, v in est.health().items()},
        )
    return out
