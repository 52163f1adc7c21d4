"""Typed request and response bodies of the REST API (they make /openapi.json)."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, Field


class Angles(BaseModel):
    """One source's latest attitude, degrees, Z-Y-X, at its vehicle time."""

    t: float = Field(description="vehicle time, s since boot")
    roll_deg: float
    pitch_deg: float
    yaw_deg: float


class ErrorStats(BaseModel):
    """RMS and max |error| (estimator − reference) per axis, roll/pitch/yaw in degrees;
    None where nothing was scored yet."""

    n: int
    window_rms_deg: list[float | None]
    session_rms_deg: list[float | None]
    session_max_deg: list[float | None]


class SourceEstimate(Angles):
    source: str
    kind: str = Field(description='"reference" (onboard, ahrs2, truth) or "estimator"')
    errors: dict[str, ErrorStats] = Field(
        default_factory=dict, description="estimators only: against 'onboard' and 'truth' when present"
    )


class EstimatesResponse(BaseModel):
    sources: dict[str, SourceEstimate]


class StreamRate(BaseModel):
    requested_hz: float
    achieved_hz: float
    ratio: float | None
    ack: str | None


class LinkStatus(BaseModel):
    address: str
    state: str
    heartbeat_age_s: float | None
    packets: int
    packets_lost: int
    loss_fraction: float
    crc_errors: int
    malformed: int
    bytes_per_s: float
    rates_hz: dict[str, float]
    stream_method: str | None
    streams: dict[str, StreamRate]


class EstimatorStatus(BaseModel):
    preset: str
    reliable: bool
    reason: str
    imu_rate_hz: float
    lag_s: float | None
    health: dict[str, Any]


class ClientStatus(BaseModel):
    id: int
    address: str
    sent_points: int
    sent_messages: int
    dropped_points: int
    dropped_frames: int
    queued_frames: int
    connected_s: float


class StatusResponse(BaseModel):
    link: LinkStatus
    vehicle: dict[str, Any]
    data_age_ms: float | None = Field(description="how old the newest attitude sample is at the server")
    imu_type: str | None
    estimators: dict[str, EstimatorStatus]
    clients: list[ClientStatus]
    viser_port: int | None
    token_required: bool


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


class GainUpdate(BaseModel):
    value: float = Field(description="new value, in the gain's unit, within its declared bounds")


class GainChange(BaseModel):
    estimator: str
    gain: str
    old: float
    new: float


class PresetRequest(BaseModel):
    preset: str | None = Field(default=None, description="preset name; omitted: the estimator's default preset")


class PresetResult(BaseModel):
    estimator: str
    preset: str
    changes: list[GainChange]


class History(BaseModel):
    """Per source [times, roll, pitch, yaw] (s, degrees), oldest first."""

    seconds: float
    points: dict[str, list[list[float]]]
