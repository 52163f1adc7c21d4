"""GET /api/status: what the page's status bar shows — link state, rates requested vs achieved,
packet loss, how old the newest data is, estimator health and reliability, the station's parts,
the viewers. Built from the station's last published snapshot: nothing is recomputed per request."""

from __future__ import annotations

from fastapi import APIRouter, Request

from gcs.server.deps import HubDep, StationDep, is_authorised
from gcs.server.models import EstimatorStatus, LinkStatus, StatusResponse

router = APIRouter(prefix="/api", tags=["status"])


@router.get("/status", response_model=StatusResponse)
async def get_status(request: Request, station: StationDep, hub: HubDep) -> StatusResponse:
    snap = station.snapshot
    link, stats, streams, estimation = snap.link, snap.link.stats, snap.streams, snap.estimation
    age = hub.data_age()
    return StatusResponse(
        link=LinkStatus(
            address=link.address,
            state=link.state,
            heartbeat_age_s=link.heartbeat_age_s,
            packets=stats.packets,
            packets_lost=stats.packets_lost,
            loss_fraction=stats.loss_fraction,
            crc_errors=stats.crc_errors,
            malformed=stats.malformed,
            nonfinite_rejected=stats.nonfinite_rejected,
            kernel_drops=stats.kernel_drops,
            bytes_per_s=stats.bytes_per_s,
            rates_hz=stats.rates_hz,
            stream_method=streams.method,
            streams=streams.messages,
            signing=link.signing,
        ),
        vehicle=snap.vehicle,
        data_age_ms=None if age is None else round(age * 1000, 1),
        imu_type=estimation.imu_type if estimation else None,
        declination_rad=estimation.declination_rad if estimation else None,
        declination_source=estimation.declination_source if estimation else "none",
        estimators={
            name: EstimatorStatus(
                preset=e.preset,
                reliable=e.reliable,
                reason=e.reason,
                imu_rate_hz=e.imu_rate_hz,
                lag_s=e.lag_s,
                health=e.health,
            )
            for name, e in (estimation.estimators.items() if estimation else ())
        },
        refused_inputs=estimation.refused_inputs if estimation else {},
        estimator_restarts=estimation.restarts if estimation else {},
        estimator_restart_reasons=estimation.restart_reasons if estimation else {},
        parts=snap.parts,
        clients=[c.snapshot() for c in hub.clients.values()],
        viser_port=request.app.state.viser_port,
        authorised=is_authorised(request),
        radio=snap.radio,
    )
