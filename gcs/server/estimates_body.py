"""GET /api/estimates's body, encoded once per published snapshot.

Every open page asks for it once a second beside the status (dashboard.js): each source's latest
attitude and each estimator's errors, all from the snapshot, so one encoding serves every request
until the next publish (a snapshot replaced between publishes is encoded by the next request)."""

from __future__ import annotations

from gcs.runtime.facade import StationFacade
from gcs.runtime.snapshots import StationSnapshot
from gcs.server.json_body import encode
from gcs.server.live_store import ERROR_REFERENCES
from gcs.server.models import EstimatesResponse, SourceEstimate


class EstimatesBodies:
    """The encoded estimates of each station, kept until its snapshot changes."""

    def __init__(self) -> None:
        self._cached: dict[int, tuple[StationSnapshot, bytes]] = {}

    def body(self, station: StationFacade) -> bytes:
        snap = station.snapshot
        cached = self._cached.get(id(station))
        if cached is None or cached[0] is not snap:
            cached = self._cached[id(station)] = (snap, encode(estimates_of(snap).model_dump(mode="json")))
        return cached[1]


#: s of vehicle time a source's latest attitude may lag the newest source's and still be current.
#: A source that stopped keeps its last value for ever (onboard-unready, the ATTITUDE sent while
#: the vehicle's EKF was not ready, ends seconds after boot): the page read it as the attitude now.
STALE_AFTER = 5.0


def estimates_of(snap: StationSnapshot) -> EstimatesResponse:
    estimation = snap.estimation
    if estimation is None:
        return EstimatesResponse(sources={})
    sources = {}
    newest = max((a.t for a in estimation.latest.values()), default=0.0)
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
            stale=newest - a.t > STALE_AFTER,
        )
    return EstimatesResponse(sources=sources)
