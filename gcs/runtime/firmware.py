"""The vehicle's firmware version, as other ground stations show it: from AUTOPILOT_VERSION
(asked for with MAV_CMD_REQUEST_MESSAGE, else the older MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES),
or from the banner ArduPilot sends as STATUSTEXT at boot and on a parameter list request
("ArduCopter V4.7.0-dev (90700977)", "APM:Copter V3.2.1 (36b405fb)" on an APM 2.5, which has no
AUTOPILOT_VERSION). The banner, when seen, wins: it also names the firmware."""

from __future__ import annotations

import asyncio
import re
from collections.abc import Callable

from gcs.mavlink.dialect import MAVLinkMessage, mavlink
from gcs.runtime.link import Link, LinkState

#: "NAME Vx.y.z[-type] (hash)" at the start of a STATUSTEXT.
BANNER = re.compile(
    r"^(?P<name>[A-Za-z][\w:]*(?: [A-Za-z]\w*)?) V(?P<version>\d+\.\d+\.\d+[\w.-]*)(?: \((?P<hash>[0-9a-fA-F]+)\))?"
)
#: FIRMWARE_VERSION_TYPE (the low byte of flight_sw_version) → the suffix ArduPilot prints.
_TYPE_SUFFIX = {
    mavlink.FIRMWARE_VERSION_TYPE_DEV: "-dev",
    mavlink.FIRMWARE_VERSION_TYPE_ALPHA: "-alpha",
    mavlink.FIRMWARE_VERSION_TYPE_BETA: "-beta",
    mavlink.FIRMWARE_VERSION_TYPE_RC: "-rc",
}
#: Seconds to wait for AUTOPILOT_VERSION after each request.
ANSWER_WAIT = 2.0


def version_of(msg: MAVLinkMessage) -> str:
    """AUTOPILOT_VERSION → "4.7.0-dev (51a3b691)": major.minor.patch, type, the git hash ArduPilot
    puts in flight_custom_version (omitted when empty)."""
    v = msg.flight_sw_version
    text = f"{v >> 24 & 0xFF}.{v >> 16 & 0xFF}.{v >> 8 & 0xFF}{_TYPE_SUFFIX.get(v & 0xFF, '')}"
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


async def request_version(link: Link, known: Callable[[], bool]) -> None:
    """After every (re)connection, ask for AUTOPILOT_VERSION until `known()`: MAV_CMD_REQUEST_MESSAGE,
    then MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES; two tries each, then wait for the next connection."""
    reconnected = asyncio.Event()
    link.state_changed.connect(lambda old, new: reconnected.set() if new == LinkState.CONNECTED else None)
    while True:
        await link.wait_connected()
        reconnected.clear()
        for command, param1 in (
            (mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION),
            (mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1),
        ) * 2:
            if known():
                break
            target = (link.target_system or 1, link.target_component or 1)
            link.send(mavlink.MAVLink_command_long_message(*target, command, 0, param1, 0, 0, 0, 0, 0, 0))
            for _ in range(int(ANSWER_WAIT / 0.1)):
                if known():
                    break
                await asyncio.sleep(0.1)
        await reconnected.wait()
