"""Which HEARTBEAT is a vehicle's: the autopilot component of a system, as Mission Planner and
QGroundControl tell them apart. Ground stations, companion computers, gimbals, cameras and radios
send heartbeats too (often on the vehicle's own link, through a router or a mesh radio); none of
them is a vehicle to request streams from or to tune. And how a vehicle is named: its autopilot,
its type and its system id ("ArduPilot-QUADROTOR-1"), in a session's folder and meta, the
reports and the fleet dataset."""

from __future__ import annotations

from gcs.mavlink.dialect import MAVLinkMessage, mavlink

#: MAV_TYPEs of components that are not vehicles (even when they claim an autopilot).
NOT_VEHICLE_TYPES = frozenset(
    getattr(mavlink, name)
    for name in (
        "MAV_TYPE_GCS",
        "MAV_TYPE_ONBOARD_CONTROLLER",
        "MAV_TYPE_GIMBAL",
        "MAV_TYPE_ADSB",
        "MAV_TYPE_CAMERA",
        "MAV_TYPE_CHARGING_STATION",
        "MAV_TYPE_FLARM",
        "MAV_TYPE_SERVO",
        "MAV_TYPE_ODID",
        "MAV_TYPE_BATTERY",
        "MAV_TYPE_PARACHUTE",
        "MAV_TYPE_LOG",
        "MAV_TYPE_OSD",
        "MAV_TYPE_IMU",
        "MAV_TYPE_GPS",
        "MAV_TYPE_WINCH",
    )
    if hasattr(mavlink, name)
)


def is_vehicle_heartbeat(msg: MAVLinkMessage) -> bool:
    """A HEARTBEAT from a vehicle's autopilot: a real autopilot and a vehicle MAV_TYPE."""
    return bool(msg.autopilot != mavlink.MAV_AUTOPILOT_INVALID and msg.type not in NOT_VEHICLE_TYPES)


_AUTOPILOTS = {
    mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA: "ArduPilot",
    mavlink.MAV_AUTOPILOT_PX4: "PX4",
    mavlink.MAV_AUTOPILOT_GENERIC: "generic",
}


def enum_name(enum: str, value: int) -> str:
    """A MAVLink enum value's name (the number when the dialect does not have it)."""
    entry = mavlink.enums.get(enum, {}).get(value)
    return entry.name if entry is not None else str(value)


def autopilot_name(code: int) -> str:
    """MAV_AUTOPILOT as people say it: "ArduPilot", "PX4", "generic", else the enum's name."""
    return _AUTOPILOTS.get(code, enum_name("MAV_AUTOPILOT", code))


def vehicle_label(autopilot: str | None, vehicle_type: str | None, sysid: int | None) -> str:
    """ "ArduPilot-QUADROTOR-1" from a HEARTBEAT's autopilot name, MAV_TYPE name and system id."""
    return f"{autopilot}-{(vehicle_type or '').removeprefix('MAV_TYPE_')}-{sysid}"


def heartbeat_label(msg: MAVLinkMessage) -> str:
    """`vehicle_label` of one vehicle's HEARTBEAT."""
    return vehicle_label(autopilot_name(msg.autopilot), enum_name("MAV_TYPE", msg.type), msg.get_srcSystem())
