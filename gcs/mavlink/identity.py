"""Which HEARTBEAT is a vehicle's: the autopilot component of a system, as Mission Planner and
QGroundControl tell them apart. Ground stations, companion computers, gimbals, cameras and radios
send heartbeats too (often on the vehicle's own link, through a router or a mesh radio); none of
them is a vehicle to request streams from or to tune. And how a vehicle is named: its autopilot,
its type and its system id ("ArduPilot-QUADROTOR-1"), in a session's folder and meta, the
reports and the fleet dataset; a DataFlash or ULog file's vehicle is named alike from what the log
says of it (the firmware's banner or name, its parameters), with "?" for what it does not say."""

from __future__ import annotations

from collections.abc import Mapping

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


def vehicle_label(autopilot: str | None, vehicle_type: str | None, sysid: int | str | None) -> str:
    """ "ArduPilot-QUADROTOR-1" from a HEARTBEAT's autopilot name, MAV_TYPE name and system id."""
    return f"{autopilot}-{(vehicle_type or '').removeprefix('MAV_TYPE_')}-{sysid}"


def heartbeat_label(msg: MAVLinkMessage) -> str:
    """`vehicle_label` of one vehicle's HEARTBEAT."""
    return vehicle_label(autopilot_name(msg.autopilot), enum_name("MAV_TYPE", msg.type), msg.get_srcSystem())


def log_label(autopilot: str | None, mav_type: int | None, sysid: int | None) -> str | None:
    """`vehicle_label` of a log's vehicle with "?" for each part the log does not say; None when it
    says none of them (the flight's vehicle stays unknown)."""
    if autopilot is None and mav_type is None and sysid is None:
        return None
    kind = enum_name("MAV_TYPE", mav_type) if mav_type is not None else "?"
    return vehicle_label(autopilot or "?", kind, "?" if sysid is None else sysid)


#: The first word of an ArduPilot banner ("ArduCopter V4.7.0-dev (90700977)", "APM:Copter V3.2.1")
#: → the firmware it names.
ARDUPILOT_FIRMWARES = {
    "ArduCopter": "copter",
    "APM:Copter": "copter",
    "ArduPlane": "plane",
    "APM:Plane": "plane",
    "ArduRover": "rover",
    "APMrover2": "rover",
    "ArduSub": "sub",
    "AntennaTracker": "tracker",
}
#: ArduCopter's FRAME_CLASS → the MAV_TYPE its HEARTBEAT sends (Copter::get_frame_mav_type; 0 is
#: "undefined", sent as a quad).
COPTER_FRAME_TYPES: dict[int, int] = {
    0: mavlink.MAV_TYPE_QUADROTOR,
    1: mavlink.MAV_TYPE_QUADROTOR,
    2: mavlink.MAV_TYPE_HEXAROTOR,
    3: mavlink.MAV_TYPE_OCTOROTOR,
    4: mavlink.MAV_TYPE_OCTOROTOR,
    5: mavlink.MAV_TYPE_HEXAROTOR,
    6: mavlink.MAV_TYPE_HELICOPTER,
    7: mavlink.MAV_TYPE_TRICOPTER,
    8: mavlink.MAV_TYPE_COAXIAL,
    9: mavlink.MAV_TYPE_COAXIAL,
    10: mavlink.MAV_TYPE_COAXIAL,
    11: mavlink.MAV_TYPE_HELICOPTER,
    12: mavlink.MAV_TYPE_DODECAROTOR,
    13: mavlink.MAV_TYPE_HELICOPTER,
}
#: Rover's FRAME_CLASS of a boat (the others are ground rovers).
ROVER_BOAT = 2
#: Firmwares of one MAV_TYPE, whatever their parameters.
ONE_TYPE_FIRMWARES: dict[str, int] = {"sub": mavlink.MAV_TYPE_SUBMARINE, "tracker": mavlink.MAV_TYPE_ANTENNA_TRACKER}
#: ArduPilot's own system id parameter (MAV_SYSID since 4.7, SYSID_THISMAV before).
ARDUPILOT_SYSID_PARAMS = ("MAV_SYSID", "SYSID_THISMAV")


def ardupilot_type(firmware: str, params: Mapping[str, float]) -> int | None:
    """The MAV_TYPE an ArduPilot firmware sends, from the parameters that choose it: ArduCopter's
    FRAME_CLASS; ArduPlane a fixed wing, a quadplane (Q_ENABLE) too unless its Q_MAV_TYPE says
    other (as the VTOL tlog's HEARTBEAT does); Rover's FRAME_CLASS (a boat or a ground rover); Sub,
    AntennaTracker theirs. None when the parameters needed are not in the log."""
    if firmware == "copter":
        frame = params.get("FRAME_CLASS")
        return None if frame is None else COPTER_FRAME_TYPES.get(int(frame))
    if firmware == "plane":
        if params.get("Q_ENABLE") == 1:  # Q_MAV_TYPE 0: "auto", a fixed wing
            chosen = params.get("Q_MAV_TYPE")
            return None if chosen is None else int(chosen) or mavlink.MAV_TYPE_FIXED_WING
        return mavlink.MAV_TYPE_FIXED_WING if params else None  # no Q_ENABLE: no quadplane
    if firmware == "rover":
        frame = params.get("FRAME_CLASS")
        if frame is None:
            return None
        return int(mavlink.MAV_TYPE_SURFACE_BOAT if int(frame) == ROVER_BOAT else mavlink.MAV_TYPE_GROUND_ROVER)
    return ONE_TYPE_FIRMWARES.get(firmware)


def dataflash_label(banners: list[str], params: Mapping[str, float]) -> str | None:
    """A DataFlash log's vehicle: ArduPilot when a MSG is a banner of its firmwares, the type its
    parameters give that firmware, the system id its parameters hold (the first value of each)."""
    firmware = next(
        (ARDUPILOT_FIRMWARES[w] for w in (b.split(" ", 1)[0] for b in banners) if w in ARDUPILOT_FIRMWARES), None
    )
    sysid = next((int(params[p]) for p in ARDUPILOT_SYSID_PARAMS if p in params), None)
    if firmware is None:
        return log_label(None, None, sysid)
    return log_label(autopilot_name(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA), ardupilot_type(firmware, params), sysid)


def ulog_label(info: Mapping[str, str], params: Mapping[str, float]) -> str | None:
    """A ULog file's vehicle: the system its `sys_name` info names ("PX4"), the MAV_TYPE and
    MAV_SYS_ID parameters PX4's HEARTBEAT is made of."""
    mav_type, sysid = params.get("MAV_TYPE"), params.get("MAV_SYS_ID")
    return log_label(
        info.get("sys_name") or None,
        None if mav_type is None else int(mav_type),
        None if sysid is None else int(sysid),
    )
