"""Which fields of a received message must be finite before the station may use it.

The link refuses a message whose field here is inf or NaN: it is counted per message type and
never published, so it reaches no live state (estimation, references, the parameter table),
no plot, no comparison, no recording and no JSON. Only fields the station reads are listed:
MAVLink uses NaN as "unknown" in many others (COMMAND_LONG params, SET_*_TARGET fields
behind an ignore mask, HIGHRES_IMU pressures, AHRS2 altitude), and those pass untouched. The
estimation's own range checks (gcs.core.plausibility) still apply to what passes here.
"""

from __future__ import annotations

import math
from operator import attrgetter, itemgetter

from gcs.mavlink.dialect import MAVLinkMessage, mavlink
from gcs.mavlink.imu_packets import IMU_AXES, ImuPacket

_ANGLES = ("roll", "pitch", "yaw")

#: message type → float fields the station reads from it and which must therefore be finite.
#: (RAW_IMU, SCALED_IMU* and GPS_RAW_INT carry integers only.)
FINITE_FIELDS: dict[str, tuple[str, ...]] = {
    "ATTITUDE": _ANGLES,  # the onboard reference
    "AHRS2": _ANGLES,  # the secondary reference
    "SIMSTATE": _ANGLES,  # the simulator's truth
    "HIGHRES_IMU": ("xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro", "xmag", "ymag", "zmag"),
}

#: PARAM_VALUE types whose param_value is a real number; the integer types carry their bytes
#: inside the float (PX4's bytewise encoding), where a NaN bit pattern is a legitimate integer.
_REAL_PARAM_TYPES = (mavlink.MAV_PARAM_TYPE_REAL32, mavlink.MAV_PARAM_TYPE_REAL64)


#: the fields of each type in one C call (every type here has several)
_VALUES = {msg_type: attrgetter(*names) for msg_type, names in FINITE_FIELDS.items()}


def nonfinite_field(msg: MAVLinkMessage, msg_type: str) -> str | None:
    """The first field of msg that must be finite and is not, or None when msg may be used."""
    if msg_type == "PARAM_VALUE":
        if msg.param_type in _REAL_PARAM_TYPES and not math.isfinite(msg.param_value):
            return "param_value"
        return None
    values = _VALUES.get(msg_type)
    # the sum of float32 values is finite exactly when every value is (inf - inf is NaN)
    if values is None or math.isfinite(sum(values(msg))):
        return None
    return next(name for name in FINITE_FIELDS[msg_type] if not math.isfinite(getattr(msg, name)))


#: IMU type → its fields that must be finite, and their values in `ImuPacket.axes` in one C call
_AXES_CHECKED = {
    msg_type: (names, itemgetter(*(IMU_AXES.index(name) for name in names)))
    for msg_type, names in FINITE_FIELDS.items()
    if set(names) <= set(IMU_AXES)
}


def nonfinite_axis(packet: ImuPacket) -> str | None:
    """`nonfinite_field` of an IMU message read from its bytes: the same verdict, the same name."""
    checked = _AXES_CHECKED.get(packet.type)
    if checked is None:
        return None
    names, values = checked
    if math.isfinite(sum(values(packet.axes))):
        return None
    return next(name for name, value in zip(names, values(packet.axes), strict=True) if not math.isfinite(value))
