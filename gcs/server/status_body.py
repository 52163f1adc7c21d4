"""GET /api/status's body, encoded once per published snapshot.

The station publishes a snapshot once a second and every open page polls the status once a
second. What comes from the snapshot (link, vehicle, streams, estimators, parts, radio: nearly all
of the body) is validated and encoded when the station publishes it (`published`, in the loop's
next turn) and reused by every request; a request then costs only its own few fields
(the newest data's age, the viewers, whether it carries the token), encoded and spliced after
them. It was encoded by the first request after a publish: 0.6 ms and more of CPU that the pages'
other requests queued behind (docs/benchmarks.md, branch `tail2`). A snapshot replaced between
publishes (a part's failure) is encoded by the next request.
"""

from __future__ import annotations

import asyncio

from gcs.runtime.facade import StationFacade
from gcs.runtime.snapshots import StationSnapshot
from gcs.server.json_body import encode
from gcs.server.live import LiveHub
from gcs.server.models import EstimatorStatus, LinkStatus, StatusResponse

#: The fields of StatusResponse each request computes for itself.
PER_REQUEST = frozenset({"data_age_ms", "clients", "viser_port", "authorised"})


class StatusBodies:
    """The encoded snapshot part of each station's status, kept until its snapshot changes."""

    def __init__(self) -> None:
        self._cached: dict[int, tuple[StationSnapshot, bytes]] = {}
        #: snapshot parts encoded so far (one per snapshot that was asked for)
        self.encoded = 0

    def published(self, station: StationFacade, snap: StationSnapshot) -> None:
        """A snapshot was published: encode it in the loop's next turn, not in the publish's own
        (which takes ~1.3 ms of CPU already: one callback of ~2.3 ms would be as long a wait
        for whatever arrives meanwhile)."""
        try:
            asyncio.get_running_loop().call_soon(self.prepare, station, snap)
        except RuntimeError:  # published outside a loop (a script, a test): encoded by the next request
            pass

    def prepare(self, station: StationFacade, snap: StationSnapshot) -> None:
        """Encode a snapshot before any request asks for it."""
        self._cached[id(station)] = (snap, encode(snapshot_status(snap)))
        self.encoded += 1

    def body(self, station: StationFacade, hub: LiveHub, viser_port: int | None, authorised: bool) -> bytes:
        """The whole JSON body: the snapshot's part, then this request's own fields."""
        snap = station.snapshot
        cached = self._cached.get(id(station))
        if cached is None or cached[0] is not snap:
            self.prepare(station, snap)
            cached = self._cached[id(station)]
        age = hub.data_age()
        own = encode(
            {
                "data_age_ms": None if age is None else round(age * 1000, 1),
                "clients": [c.snapshot().as_dict() for c in hub.clients.values()],
                "viser_port": viser_port,
                "authorised": authorised,
            }
        )
        return cached[1][:-1] + b"," + own[1:]


def snapshot_status(snap: StationSnapshot) -> dict:
    """The snapshot's fields of StatusResponse, validated by the model, as JSON-ready values."""
    link, stats, streams, estimation = snap.link, snap.link.stats, snap.streams, snap.estimation
    model = StatusResponse(
        link=LinkStatus(
            address=link.address,
            state=link.state,
            lost_reason=link.lost_reason,
            open_error=link.open_error,
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
        data_age_ms=None,
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
        clients=[],
        viser_port=None,
        authorised=False,
        radio=snap.radio,
    )
    return model.model_dump(mode="json", exclude=set(PER_REQUEST))
