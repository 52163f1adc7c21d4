"""The MAVLink parameter codec, shared by the client (gcs.runtime.params) and the simulator:
names, MAV_PARAM_TYPE values on the wire (ArduPilot's float cast and PX4's bytewise integers),
and the float32 the vehicle stores.
"""

from __future__ import annotations

import math
import struct

from gcs.mavlink.dialect import MARKER_V2, MAVLinkMessage, mavlink

#: MAV_PARAM_TYPE → struct format of the integer inside a bytewise-encoded float.
_INT_FORMATS = {
    mavlink.MAV_PARAM_TYPE_UINT8: "<B",
    mavlink.MAV_PARAM_TYPE_INT8: "<b",
    mavlink.MAV_PARAM_TYPE_UINT16: "<H",
    mavlink.MAV_PARAM_TYPE_INT16: "<h",
    mavlink.MAV_PARAM_TYPE_UINT32: "<I",
    mavlink.MAV_PARAM_TYPE_INT32: "<i",
}
_FLOAT_TYPES = (mavlink.MAV_PARAM_TYPE_REAL32, mavlink.MAV_PARAM_TYPE_REAL64)
_MAX_NAME = 16
_FLOAT32_MAX = 3.4028234663852886e38


class ParamError(Exception):
    """A parameter operation failed; the message says which parameter and why."""


def type_name(param_type: int) -> str:
    """MAV_PARAM_TYPE_REAL32 → "REAL32"."""
    entry = mavlink.enums["MAV_PARAM_TYPE"].get(param_type)
    return entry.name.removeprefix("MAV_PARAM_TYPE_") if entry else str(param_type)


def float32(value: float) -> float:
    """The value as the vehicle's float32 holds it."""
    stored: float = struct.unpack("<f", struct.pack("<f", value))[0]
    return stored


def format_value(value: float) -> str:
    """The shortest text that reads back as the same float32 (0.15, not 0.15000000596...), or an
    integer as an integer: how values appear in files, messages and the UI."""
    if isinstance(value, int):
        return str(value)
    if math.isfinite(value) and value == int(value) and abs(value) < 2**24:
        return str(int(value))
    for digits in range(1, 10):
        text = f"{value:.{digits}g}"
        if float32(float(text)) == float32(value):
            return text
    return repr(value)


def same_value(a: float, b: float) -> bool:
    """Equal as the vehicle stores them (float32), within a relative 1e-6 for firmware rounding."""
    return math.isclose(float32(a), float32(b), rel_tol=1e-6, abs_tol=0.0)


def decode(raw: bytes, param_type: int, bytewise: bool) -> int | float:
    """A PARAM_VALUE's 4 value bytes → the typed value."""
    wire: float = struct.unpack("<f", raw)[0]
    if param_type in _FLOAT_TYPES or param_type not in _INT_FORMATS:
        return wire
    if bytewise:
        fmt = _INT_FORMATS[param_type]
        integer: int = struct.unpack(fmt, raw[: struct.calcsize(fmt)])[0]
        return integer
    return int(wire)


def value_bytes(msg: MAVLinkMessage) -> bytes:
    """The 4 bytes of PARAM_VALUE.param_value as sent, read from the packet itself: a float32
    signalling-NaN pattern (bytewise integers) would not survive a trip through a Python float.
    (pymavlink's get_payload() starts inside the MAVLink 2 header, so it is not used.)"""
    buf = msg.get_msgbuf()
    if not buf:
        return struct.pack("<f", msg.param_value)
    start = 10 if buf[0] == MARKER_V2 else 6  # header length, MAVLink 2 / 1
    return bytes(buf[start : start + 4]).ljust(4, b"\0")  # MAVLink 2 trims trailing zero bytes


def encode(name: str, value: float, param_type: int, bytewise: bool) -> tuple[float, int | float]:
    """(the PARAM_SET param_value float, the typed value the vehicle should store), or ParamError
    naming what cannot be sent."""
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
        raise ParamError(f"{name}: {value!r} is not a finite number")
    if param_type in _FLOAT_TYPES or param_type not in _INT_FORMATS:
        if abs(value) > _FLOAT32_MAX:
            raise ParamError(f"{name}: {value} does not fit a 32-bit float")
        return float(value), float32(value)
    if value != int(value):
        raise ParamError(f"{name} is {type_name(param_type)}: {value} is not an integer")
    fmt = _INT_FORMATS[param_type]
    bits = 8 * struct.calcsize(fmt)
    lo, hi = (0, 2**bits - 1) if fmt.isupper() else (-(2 ** (bits - 1)), 2 ** (bits - 1) - 1)
    if not lo <= value <= hi:
        raise ParamError(f"{name} is {type_name(param_type)}: {int(value)} is outside [{lo}, {hi}]")
    if not bytewise:
        if abs(value) > 2**24:
            raise ParamError(f"{name}: {int(value)} cannot be sent exactly as a float (|value| > 2^24)")
        return float(value), int(value)
    raw = struct.pack(fmt, int(value)).ljust(4, b"\0")
    word = struct.unpack("<I", raw)[0]
    if word & 0x7F800000 == 0x7F800000 and word & 0x007FFFFF and not word & 0x00400000:
        raise ParamError(f"{name}: {int(value)} is a signalling-NaN bit pattern that cannot be sent bytewise")
    return struct.unpack("<f", raw)[0], int(value)


def check_name(name: str) -> None:
    if not isinstance(name, str) or not name or len(name) > _MAX_NAME or not name.isascii() or " " in name:
        raise ParamError(f"{name!r} is not a parameter name (1-{_MAX_NAME} ASCII characters, no spaces)")


def param_name(msg: MAVLinkMessage) -> str:
    """PARAM_VALUE / PARAM_SET / PARAM_REQUEST_READ param_id as text (str or NUL-padded bytes)."""
    raw = msg.param_id
    return (raw if isinstance(raw, str) else raw.decode(errors="replace")).rstrip("\x00")
