"""A firmware's version as other ground stations show it, from what the autopilot says of itself:
AUTOPILOT_VERSION's flight_sw_version ("4.7.0-dev (51a3b691)"), or the banner ArduPilot sends as
STATUSTEXT at boot and logs as a DataFlash MSG ("ArduCopter V4.7.0-dev (90700977)", "APM:Copter
V3.2.1 (36b405fb)" on an APM 2.5, which has no AUTOPILOT_VERSION). A banner also names the firmware.
"""

from __future__ import annotations

import re

from gcs.mavlink.dialect import MAVLinkMessage, mavlink

#: "NAME Vx.y.z[-type] (hash)" at the start of a STATUSTEXT.
BANNER = re.compile(
    r"^(?P<name>[A-Za-z][\w:]*(?: [A-Za-z]\w*)?) V(?P<version>\d+\.\d+\.\d+[\w.-]*)(?: \((?P<hash>[0-9a-fA-F]+)\))?"
)
#: FIRMWARE_VERSION_TYPE (the low byte of a packed version) → the suffix ArduPilot prints.
_TYPE_SUFFIX = {
    mavlink.FIRMWARE_VERSION_TYPE_DEV: "-dev",
    mavlink.FIRMWARE_VERSION_TYPE_ALPHA: "-alpha",
    mavlink.FIRMWARE_VERSION_TYPE_BETA: "-beta",
    mavlink.FIRMWARE_VERSION_TYPE_RC: "-rc",
}


def packed_version(v: int) -> str:
    """0xMMmmppTT (AUTOPILOT_VERSION's flight_sw_version, a ULog's ver_sw_release) → "4.7.0-dev"."""
    return f"{v >> 24 & 0xFF}.{v >> 16 & 0xFF}.{v >> 8 & 0xFF}{_TYPE_SUFFIX.get(v & 0xFF, '')}"


def version_of(msg: MAVLinkMessage) -> str:
    """AUTOPILOT_VERSION → "4.7.0-dev (51a3b691)": major.minor.patch, type, the git hash ArduPilot
    puts in flight_custom_version (omitted when empty)."""
    text = packed_version(msg.flight_sw_version)
    custom = bytes(b & 0xFF for b in msg.flight_custom_version).rstrip(b"\0")
    if custom and custom.isascii() and custom.decode().isalnum():
        text += f" ({custom.decode()})"
    return text


def banner_version(text: str) -> str | None:
    """A STATUSTEXT banner → "ArduPlane 4.7.0-dev (51a3b691)", or None for any other text."""
    m = BANNER.match(text)
    if m is None:
        return None
    return f"{m['name']} {m['version']}" + (f" ({m['hash']})" if m["hash"] else "")
