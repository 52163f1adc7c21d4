"""Asking the vehicle for its firmware version: AUTOPILOT_VERSION, with MAV_CMD_REQUEST_MESSAGE,
else the older MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES. ArduPilot also sends its banner as
STATUSTEXT at boot and on a parameter list request; the banner, when seen, wins (it also names the
firmware). Both are read by gcs.mavlink.firmware_version."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from gcs.mavlink.dialect import mavlink
from gcs.runtime.link import Link, LinkState

#: Seconds to wait for AUTOPILOT_VERSION after each request.
ANSWER_WAIT = 2.0


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
