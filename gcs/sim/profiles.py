"""How each simulated autopilot behaves on the link: protocol version, stream groups, default
rates, rate caps, commands it knows, parameter encoding. The firmware facts: docs/vehicles.md.

- apm25: ArduCopter 3.2.1 on an APM 2.5 (AVR): MAVLink 1 only, streams only per group via
  REQUEST_DATA_STREAM (SRx default 0), ≤ 50 Hz, no SET_MESSAGE_INTERVAL, one IMU, DCM only.
- pixhawk: ArduCopter 4.x: MAVLink 2, groups as current ArduPilot plus per-message
  SET_MESSAGE_INTERVAL ≤ 0.8 × 400 Hz loop, two IMUs, EKF3 attitude with DCM in AHRS2.
- px4: PX4 1.x: MAVLink 2, no stream groups, per-message intervals only, some messages on by
  default ("normal" mode rates), bytewise parameter encoding.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from gcs.mavlink.dialect import mavlink
from gcs.sim import param_tables
from gcs.sim.param_tables import Row

# MAV_DATA_STREAM group ids (common.xml).
RAW_SENSORS = mavlink.MAV_DATA_STREAM_RAW_SENSORS
EXTENDED_STATUS = mavlink.MAV_DATA_STREAM_EXTENDED_STATUS
POSITION = mavlink.MAV_DATA_STREAM_POSITION
EXTRA1 = mavlink.MAV_DATA_STREAM_EXTRA1
EXTRA3 = mavlink.MAV_DATA_STREAM_EXTRA3


@dataclass(frozen=True)
class Profile:
    """One autopilot's link behaviour.

    groups: REQUEST_DATA_STREAM id → message names in that group (empty: requests ignored).
    group_share: message → fraction of its group's rate (APM sends SENSOR_OFFSETS at ~1/11).
    default_rates: message → Hz streamed at boot (HEARTBEAT is always 1 Hz and not listed).
    group_cap_hz / interval_cap_hz: highest rate per group request / per SET_MESSAGE_INTERVAL
    (0: command unsupported). loop_hz: main loop, where its AHRS runs. param_rows: its parameter table.
    """

    name: str
    mavlink1: bool
    autopilot: int
    messages: tuple[str, ...]
    groups: dict[int, tuple[str, ...]]
    param_rows: Callable[[], list[Row]]
    group_share: dict[str, float] = field(default_factory=dict)
    default_rates: dict[str, float] = field(default_factory=dict)
    group_cap_hz: float = 50.0
    interval_cap_hz: float = 0.0
    loop_hz: float = 400.0
    imu_count: int = 1
    param_bytewise: bool = False
    knows_autopilot_version: bool = False
    flight_sw_version: int = 0
    capabilities: int = 0
    custom_mode: int = 0
    #: the STATUSTEXT ArduPilot sends on PARAM_REQUEST_LIST ("" for none)
    banner: str = ""
    log_time_ms: bool = False  # onboard log in ArduCopter 3.1-3.2's TimeMS layouts (gcs.sim.dataflash)

    @property
    def message_intervals(self) -> bool:
        return self.interval_cap_hz > 0


_ARDUPILOT_CAPS = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_FTP
    | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
)
_PX4_CAPS = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
)


def _version(major: int, minor: int, patch: int) -> int:
    """AUTOPILOT_VERSION.flight_sw_version: major, minor, patch, FIRMWARE_VERSION_TYPE_OFFICIAL."""
    return (major << 24) | (minor << 16) | (patch << 8) | mavlink.FIRMWARE_VERSION_TYPE_OFFICIAL


APM25 = Profile(
    name="apm25",
    mavlink1=True,
    autopilot=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
    messages=(
        "HEARTBEAT",
        "RAW_IMU",
        "SCALED_PRESSURE",
        "SENSOR_OFFSETS",
        "SYS_STATUS",
        "GPS_RAW_INT",
        "GLOBAL_POSITION_INT",
        "ATTITUDE",
        "SIMSTATE",
        "AHRS",
    ),
    groups={  # ArduCopter/GCS_Mavlink.pde (3.2.1)
        RAW_SENSORS: ("RAW_IMU", "SCALED_PRESSURE", "SENSOR_OFFSETS"),
        EXTENDED_STATUS: ("SYS_STATUS", "GPS_RAW_INT"),
        POSITION: ("GLOBAL_POSITION_INT",),
        EXTRA1: ("ATTITUDE", "SIMSTATE"),
        EXTRA3: ("AHRS",),
    },
    param_rows=param_tables.arducopter_32,
    group_share={"SENSOR_OFFSETS": 1 / 11},
    loop_hz=100.0,
    banner="APM:Copter V3.2.1 (36b405fb)",
    log_time_ms=True,
)

PIXHAWK = Profile(
    name="pixhawk",
    mavlink1=False,
    autopilot=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
    # ArduPilot sends the messages due in one scheduler slot in ap_message order (MSG_AHRS 1,
    # MSG_AHRS2 2, MSG_ATTITUDE 3, ..., MSG_RAW_IMU 15, ..., MSG_SIMSTATE): AHRS2 before ATTITUDE.
    messages=(
        "HEARTBEAT",
        "AHRS",
        "AHRS2",
        "ATTITUDE",
        "GLOBAL_POSITION_INT",
        "SYS_STATUS",
        "RAW_IMU",
        "SCALED_IMU2",
        "SCALED_PRESSURE",
        "GPS_RAW_INT",
        "SIMSTATE",
        "EKF_STATUS_REPORT",
        "AUTOPILOT_VERSION",
    ),
    groups={  # libraries/GCS_MAVLink/GCS_MAVLink_Parameters.cpp (4.x), messages the sim has
        RAW_SENSORS: ("RAW_IMU", "SCALED_IMU2", "SCALED_PRESSURE"),
        EXTENDED_STATUS: ("SYS_STATUS", "GPS_RAW_INT"),
        POSITION: ("GLOBAL_POSITION_INT",),
        EXTRA1: ("ATTITUDE", "SIMSTATE", "AHRS2"),
        EXTRA3: ("AHRS", "EKF_STATUS_REPORT"),
    },
    param_rows=param_tables.arducopter_4,
    interval_cap_hz=320.0,  # 0.8 × SCHED_LOOP_RATE 400 (ardupilot#28144)
    loop_hz=400.0,
    imu_count=2,
    knows_autopilot_version=True,
    flight_sw_version=_version(4, 5, 7),
    capabilities=_ARDUPILOT_CAPS,
)

PX4 = Profile(
    name="px4",
    mavlink1=False,
    autopilot=mavlink.MAV_AUTOPILOT_PX4,
    messages=(
        "HEARTBEAT",
        "HIGHRES_IMU",
        "ATTITUDE",
        "ATTITUDE_QUATERNION",
        "GPS_RAW_INT",
        "SYS_STATUS",
        "GLOBAL_POSITION_INT",
        "SIMSTATE",
        "ESTIMATOR_STATUS",
        "AUTOPILOT_VERSION",
    ),
    groups={},
    param_rows=param_tables.px4_115,
    # mavlink_main.cpp configure_streams_to_default, "normal" mode; SIMSTATE is the sim's truth.
    default_rates={
        "ATTITUDE": 15.0,
        "GPS_RAW_INT": 1.0,
        "SYS_STATUS": 1.0,
        "GLOBAL_POSITION_INT": 5.0,
        "SIMSTATE": 15.0,
        "ESTIMATOR_STATUS": 0.5,
    },
    interval_cap_hz=1000.0,
    loop_hz=250.0,
    param_bytewise=True,
    knows_autopilot_version=True,
    flight_sw_version=_version(1, 15, 0),
    capabilities=_PX4_CAPS,
    custom_mode=1 << 16,  # PX4_CUSTOM_MAIN_MODE_MANUAL in bits 16-23
)

PROFILES: dict[str, Profile] = {p.name: p for p in (APM25, PIXHAWK, PX4)}


def get_profile(name: str) -> Profile:
    try:
        return PROFILES[name]
    except KeyError:
        raise ValueError(f"unknown profile {name!r}; choose one of {', '.join(PROFILES)}") from None
