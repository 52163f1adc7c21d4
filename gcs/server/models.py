"""Typed request and response bodies of the REST API (they make /openapi.json)."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from gcs.runtime.protocol import ProtocolState
from gcs.runtime.snapshots import ErrorStats, RadioSnapshot, SigningSnapshot, StreamRate, VehicleSnapshot
from gcs.runtime.supervisor import PartStatus
from gcs.server.client_feed import ClientSnapshot


class Body(BaseModel):
    """A request body: its declared fields only, each of its declared type. Parsed leniently,
    `{"value": true}` set a gain to 1.0 and `{"name": "seed000"}` (a misspelt key) reset an
    estimator to its default preset, both answered 200 as if meant."""

    model_config = ConfigDict(extra="forbid", strict=True)


class Angles(BaseModel):
    """One source's latest attitude, degrees, Z-Y-X, at its vehicle time."""

    t: float = Field(description="vehicle time, s since boot")
    roll_deg: float
    pitch_deg: float
    yaw_deg: float


class SourceEstimate(Angles):
    source: str
    kind: str = Field(description='"reference" (onboard, ahrs2, truth) or "estimator"')
    errors: dict[str, ErrorStats] = Field(
        default_factory=dict, description="estimators only: against 'onboard' and 'truth' when present"
    )
    stale: bool = Field(
        default=False,
        description="its latest attitude is over STALE_AFTER s of vehicle time older than the newest source's: "
        "it stopped (onboard-unready once the vehicle's EKF is ready), its value is not current",
    )


class EstimatesResponse(BaseModel):
    sources: dict[str, SourceEstimate]


class LinkStatus(BaseModel):
    address: str
    state: str
    lost_reason: str | None = Field(
        default=None, description="while lost: why (no heartbeat for N s, the serial port gone, the TCP peer closed)"
    )
    open_error: str | None = Field(
        default=None, description="while its transport cannot be opened: why (cannot open ADDRESS: Connection refused)"
    )
    heartbeat_age_s: float | None
    packets: int
    packets_lost: int
    loss_fraction: float
    crc_errors: int
    malformed: int
    nonfinite_rejected: dict[str, int] = Field(
        default_factory=dict, description="packets refused for inf/NaN in a field the station reads, per type"
    )
    kernel_drops: int = Field(default=0, description="UDP datagrams the kernel dropped before they were read")
    bytes_per_s: float
    rates_hz: dict[str, float]
    stream_method: str | None
    streams: dict[str, StreamRate]
    signing: SigningSnapshot | None = Field(default=None, description="MAVLink 2 signing counters (None: off)")


class EstimatorStatus(BaseModel):
    preset: str
    reliable: bool
    reason: str
    imu_rate_hz: float
    lag_s: float | None = Field(description="how late the estimator is behind ATTITUDE, s (positive: behind)")
    health: dict[str, Any]


class StatusResponse(BaseModel):
    link: LinkStatus
    vehicle: VehicleSnapshot
    data_age_ms: float | None = Field(description="how old the newest attitude sample is at the server")
    imu_type: str | None
    declination_rad: float | None = Field(default=None, description="the declination the estimators use")
    declination_source: str = Field(
        default="none", description='where it came from: "vehicle COMPASS_DEC", "WMM at lat,lon" or "none"'
    )
    estimators: dict[str, EstimatorStatus]
    refused_inputs: dict[str, int] = Field(
        default_factory=dict,
        description="samples kept from the estimators as implausible (inf, NaN, beyond any sensor), by reason",
    )
    estimator_restarts: dict[str, int] = Field(
        default_factory=dict, description="restarts after a non-finite state or an error in the estimator"
    )
    estimator_restart_reasons: dict[str, str] = Field(default_factory=dict, description="why each last restarted")
    parts: list[PartStatus] = Field(description="the station's supervised parts; a failed one carries its error")
    clients: list[ClientSnapshot]
    viser_port: int | None
    authorised: bool = Field(description="this request carries the token that changes need")
    radio: RadioSnapshot | None = Field(
        default=None,
        description="the telemetry radio's state and budget: per stream wanted, predicted, requested, achieved",
    )


class GainInfo(BaseModel):
    name: str
    value: float
    default: float
    min: float
    max: float
    unit: str
    meaning: str
    scale: str = Field(description='slider scale: "linear" (value = position) or "log" (value = 10**position)')
    slider_min: float
    slider_max: float
    slider_step: float


class EstimatorGains(BaseModel):
    name: str
    preset: str
    presets: list[str]
    default_preset: str
    gains: list[GainInfo]


class GainUpdate(Body):
    value: float = Field(allow_inf_nan=False, description="new value, in the gain's unit, within its declared bounds")


class GainChange(BaseModel):
    estimator: str
    gain: str
    old: float
    new: float


class PresetRequest(Body):
    preset: str | None = Field(default=None, description="preset name; omitted: the estimator's default preset")


class PresetResult(BaseModel):
    estimator: str
    preset: str
    changes: list[GainChange]


class History(BaseModel):
    """Per source [times, roll, pitch, yaw] (s, degrees), oldest first, and the same per
    "estimator|reference" error (estimator − reference, degrees, wrapped to ±180°)."""

    seconds: float
    resolution_s: float = Field(description="0: every sample; else the width (s) of the min/max columns")
    points: dict[str, list[list[float]]]
    errors: dict[str, list[list[float]]]


class ProtocolStart(Body):
    name: str = Field(description="a shipped protocol (GET /api/protocol lists them) or a TOML file on the server")
    detect_source: str | None = Field(default=None, description="source that detects the holds; omitted: the file's")


class ProtocolRun(BaseModel):
    """A test protocol run: where it is, and every source's figures per completed step
    (gcs.core.protocol.SourceMetrics fields; null where a figure could not be had)."""

    state: ProtocolState
    running: bool
    detect_source: str
    results: list[dict[str, float | int | str | None]]


class ProtocolStatus(BaseModel):
    available: list[str]
    run: ProtocolRun | None


class VehicleSummary(BaseModel):
    """One vehicle the station serves (GET /api/vehicles)."""

    sysid: int | None = Field(description="None: nothing heard yet (the first vehicle's place)")
    compid: int | None
    link: str = Field(description="the address it is heard on")
    state: str = Field(description="waiting, connected or lost: its own heartbeats")
    lost_reason: str | None = Field(default=None, description="while lost: why")
    autopilot: str | None
    vehicle_type: str | None
    first: bool = Field(description="served at the one-vehicle URLs too (/api/status, /ws/live, ...)")
    prefix: str | None = Field(description="its URLs: /api/vehicles/{sysid}/status, .../ws/live, ...")
