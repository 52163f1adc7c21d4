"""The vehicle's onboard logs over REST: a download into the recording folder, where the replay
panel finds it next to the sessions recorded live.

GET  /api/onboard-logs            the logs the vehicle listed last, and the download's progress
POST /api/onboard-logs/download   list the logs and download one (default the latest) (token)
"""

from __future__ import annotations

import dataclasses
from typing import Any

from fastapi import APIRouter, Depends, status
from pydantic import Field

from gcs.server.deps import TOKEN, StationDep
from gcs.server.models import Body
from gcs.server.ratelimit import rate_limited

router = APIRouter(prefix="/api/onboard-logs", tags=["onboard logs"])


class DownloadRequest(Body):
    log: int | None = Field(default=None, ge=1, description="log id; none: the latest")


def _state(station: StationDep) -> dict[str, Any]:
    logs = station.onboard_logs
    progress = logs.progress
    return {
        "logs": [dataclasses.asdict(e) for e in logs.entries],
        "progress": {**dataclasses.asdict(progress), "fraction": round(progress.fraction, 4)},
    }


@router.get("")
async def onboard_logs(station: StationDep) -> dict[str, Any]:
    return _state(station)


@router.post(
    "/download",
    status_code=status.HTTP_202_ACCEPTED,
    dependencies=[TOKEN, Depends(rate_limited("onboard log download"))],
)
async def start_download(body: DownloadRequest, station: StationDep) -> dict[str, Any]:
    started = station.start_log_download(body.log)
    return {"download": "started" if started else "already running", **_state(station)}
