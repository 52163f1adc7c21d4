"""Which HEARTBEAT is a vehicle's: the autopilot component of a system, as Mission Planner and
QGroundControl tell them apart. Ground stations, companion computers, gimbals, cameras and radios
send heartbeats too (often on the vehicle's own link, through a router or a mesh radio); none of
them is a vehicle to request streams from or to tune."""

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
