"""The station's state as typed, frozen values: what the server, the CLI and the recorder read.

The station publishes one `StationSnapshot` at a fixed rate (and when a part fails); readers never
touch the live objects. Numbers that are unknown are None, never NaN (JSON has no NaN).
Angles a person reads are in degrees, as the field names say.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from gcs.mavlink.signing import SigningSnapshot as SigningSnapshot  # re-exported: the server reads it here
from gcs.runtime.supervisor import PartStatus


def finite(x: float | None) -> float | None:
    """None for a missing or non-finite number."""
    return None if x is None or not math.isfinite(x) else x


@dataclass(frozen=True, slots=True)
class LinkCounters:
    packets: int
    bytes_in: int
    bytes_out: int
    packets_out: int
    bytes_per_s: float
    rates_hz: dict[str, float]
    counts: dict[str, int]
    crc_errors: int
    malformed: int
    bytes_skipped: int
    unknown_messages: int
    packets_lost: int
    loss_fraction: float
    lost_by_source: dict[str, int]
    mavlink1_packets: int
    mavlink2_packets: int
    #: packets refused by the link for inf/NaN in a field the station reads (gcs.mavlink.finite), per type
    nonfinite_rejected: dict[str, int] = field(default_factory=dict)
    #: datagrams the kernel dropped on the UDP socket because we read too slowly (SO_RXQ_OVFL)
    kernel_drops: int = 0


@dataclass(frozen=True, slots=True)
class LinkNote:
    """A link event as an engineer reads it (state change, reconnect, baud detection...)."""

    wall_time: float
    kind: str
    detail: str


@dataclass(frozen=True, slots=True)
class LinkSnapshot:
    name: str
    address: str
    state: str
    transport_open: bool
    baud: int | str | None
    target_system: int | None
    target_component: int | None
    mavlink_version: int | None
    heartbeat_age_s: float | None
    stats: LinkCounters
    events: list[LinkNote]
    #: MAVLink 2 signing on this link (None: off)
    signing: SigningSnapshot | None = None
    #: while the state is lost: why ("no heartbeat for 3 s", "/dev/ttyUSB0 closed: the device is
    #: gone (Input/output error)", "tcp:HOST:PORT closed: the remote end closed the connection")
    lost_reason: str | None = None
    #: while its transport cannot be opened: why ("cannot open /dev/ttyUSB0: Permission denied")
    open_error: str | None = None


@dataclass(frozen=True, slots=True)
class StreamRate:
    requested_hz: float
    achieved_hz: float
    ratio: float | None
    ack: str | None
    #: the rate the vehicle took (after a refusal: the highest it allows), and how it was asked
    accepted_hz: float | None = None
    method: str | None = None  # SET_MESSAGE_INTERVAL | REQUEST_DATA_STREAM
    #: why accepted differs from requested: the refusal and the vehicle's STATUSTEXT
    reason: str | None = None


@dataclass(frozen=True, slots=True)
class StreamsSnapshot:
    method: str | None  # "SET_MESSAGE_INTERVAL", "REQUEST_DATA_STREAM" or "mixed" once decided
    requests_sent: int
    messages: dict[str, StreamRate]


@dataclass(frozen=True, slots=True)
class AutopilotMessage:
    """One STATUSTEXT: what the autopilot told the pilot (pre-arm failures, failsafes, arming)."""

    wall_time: float
    severity: int  # MAV_SEVERITY: 0 emergency … 7 debug
    severity_name: str  # "EMERGENCY" … "DEBUG"
    text: str


@dataclass(frozen=True, slots=True)
class VehicleSnapshot:
    sysid: int | None
    compid: int | None
    autopilot: str | None
    vehicle_type: str | None
    mavlink_version: int | None
    armed: bool
    custom_mode: int | None
    system_status: str | None
    firmware: str | None
    reboots: int
    heartbeats: int
    #: two vehicles send as this one system id: their clocks or their packets' sequence numbers
    #: interleave (gcs.runtime.boot_clock, gcs.runtime.sequence_watch)
    two_senders: bool = False
    #: links where another vehicle (a heartbeat of another MAV_TYPE) sends as this system id: not
    #: served, "tcp:127.0.0.1:5770 (MAV_TYPE_QUADROTOR)" (VehicleState.others)
    others: list[str] = field(default_factory=list)
    #: flight mode by name (ArduPilot per vehicle type, PX4 main/sub mode; the number when unknown)
    mode: str | None = None
    battery_v: float | None = None
    battery_a: float | None = None
    battery_remaining_pct: int | None = None
    #: SYS_STATUS sensors present and enabled but not healthy, by name
    sensors_unhealthy: list[str] = field(default_factory=list)
    gps_fix: str | None = None  # "3D", "RTK fixed", ...
    gps_satellites: int | None = None
    gps_hdop: float | None = None
    #: the autopilot estimator's flags set, by name: EKF_STATUS_REPORT's (ArduPilot) or
    #: ESTIMATOR_STATUS's (PX4); the largest of EKF_STATUS_REPORT's variances (None from PX4)
    ekf_flags: list[str] = field(default_factory=list)
    ekf_variance_max: float | None = None
    #: newest first
    messages: list[AutopilotMessage] = field(default_factory=list)
    #: GPS positions on a local grid, metres north and east of the first 3D fix, about one a second
    track_ne_m: list[tuple[float, float]] = field(default_factory=list)


@dataclass(frozen=True, slots=True)
class OutputSnapshot:
    address: str
    open: bool
    packets_out: int
    packets_in: int


@dataclass(frozen=True, slots=True)
class ErrorStats:
    """|estimator − reference| per axis (roll, pitch, yaw), degrees."""

    n: int
    window_rms_deg: list[float | None]
    window_max_deg: list[float | None]
    session_rms_deg: list[float | None]
    session_max_deg: list[float | None]


@dataclass(frozen=True, slots=True)
class EstimatorSnapshot:
    preset: str
    gains: dict[str, float]
    health: dict[str, float | str | tuple[float, ...] | None]
    reliable: bool
    reason: str
    imu_rate_hz: float
    lag_s: float | None  # > 0: the estimator is behind the onboard attitude
    dropped: int
    errors: dict[str, ErrorStats]  # per reference


@dataclass(frozen=True, slots=True)
class SourceAttitude:
    """One source's latest attitude at its vehicle time, degrees, Z-Y-X."""

    source: str
    kind: str  # "reference" (onboard, ahrs2, truth) or "estimator"
    t: float
    roll_deg: float
    pitch_deg: float
    yaw_deg: float


@dataclass(frozen=True, slots=True)
class RecordingSnapshot:
    state: str  # off | recording | failed | stopped
    folder: str | None
    root: str | None
    bytes_written: int
    last_flush_age_s: float | None
    packets_received: int
    packets_sent: int
    dropped: int
    error: str | None
    recovered: list[dict[str, object]] = field(default_factory=list)


@dataclass(frozen=True, slots=True)
class EstimationSnapshot:
    imu_type: str | None
    imu_samples: int
    declination_rad: float | None
    estimators: dict[str, EstimatorSnapshot]
    latest: dict[str, SourceAttitude]
    refused_inputs: dict[str, int] = field(default_factory=dict)  # implausible samples, by reason
    restarts: dict[str, int] = field(default_factory=dict)  # estimators restarted after a non-finite state or an error
    restart_reasons: dict[str, str] = field(default_factory=dict)  # why each last restarted
    #: where declination_rad came from: "vehicle COMPASS_DEC", "WMM at lat,lon" or "none"
    declination_source: str = "none"


@dataclass(frozen=True, slots=True)
class RadioStatus:
    """The telemetry radio's last RADIO_STATUS (SiK's 0-255 signal scale; txbuf: % of its buffer free)."""

    rssi: int
    remrssi: int
    noise: int
    remnoise: int
    txbuf: int
    rxerrors: int
    fixed: int
    age_s: float


@dataclass(frozen=True, slots=True)
class RadioStream:
    """One stream on the radio's budget: what the estimators want, what fits (predicted before
    requesting), what the station asked for, what arrives, and its cost at the requested rate."""

    wanted_hz: float
    predicted_hz: float
    requested_hz: float
    achieved_hz: float
    cost_bps: float


@dataclass(frozen=True, slots=True)
class RadioSnapshot:
    """The radio link's budget (gcs.runtime.radio): present once a RADIO_STATUS has arrived."""

    present: bool
    status: RadioStatus | None
    capacity_bps: float
    budget_bps: float  # this vehicle's share of BUDGET_SHARE × capacity
    shared_by: int  # vehicles heard on the link, splitting its budget
    used_bps: float
    predicted_scale: float
    scale: float
    choice: str
    streams: dict[str, RadioStream]
    ignored_status: int = 0  # RADIO_STATUS packets from another component than a radio's


@dataclass(frozen=True, slots=True)
class StationSnapshot:
    published: float  # UNIX time
    link: LinkSnapshot
    vehicle: VehicleSnapshot
    streams: StreamsSnapshot
    outputs: list[OutputSnapshot]
    estimation: EstimationSnapshot | None
    recording: RecordingSnapshot
    parts: list[PartStatus]
    radio: RadioSnapshot | None = None
