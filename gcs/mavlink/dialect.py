"""The one MAVLink dialect gcs speaks, and packet encoding in either protocol version.

pymavlink's `all` dialect: ArduPilot's `ardupilotmega` (so APM-era messages such as AHRS and
SENSOR_OFFSETS decode) plus every other public dialect, so that as few packets as possible
are of an unknown id (those cannot be CRC-checked, see framing.py). The v2.0 module parses MAVLink 1
and 2 packets alike; an `Encoder` writes MAVLink 1 for vehicles that only speak it (APM 2.5) and MAVLink 2 otherwise.
"""

from __future__ import annotations

from typing import TypeAlias

from pymavlink.dialects.v20 import all as mavlink

__all__ = ["MARKER_V1", "MARKER_V2", "Encoder", "MAVError", "MAVLink", "MAVLinkMessage", "mavlink"]

MAVLink = mavlink.MAVLink
#: A decoded or built message. pymavlink ships no type information and creates each message's
#: fields at run time, so this is Any to mypy: the dynamic boundary, named here once.
MAVLinkMessage: TypeAlias = mavlink.MAVLink_message
MAVError = mavlink.MAVError

#: Start-of-frame markers.
MARKER_V1 = mavlink.PROTOCOL_MARKER_V1  # 0xFE
MARKER_V2 = mavlink.PROTOCOL_MARKER_V2  # 0xFD


class Encoder:
    """Turns pymavlink message objects into wire bytes for one (sysid, compid).

    Keeps the packet sequence number. `mavlink1` selects the wire version: APM 2.5 firmware
    (ArduCopter 3.2.1, ArduPlane 3.4.0) only parses MAVLink 1.
    """

    def __init__(self, sysid: int, compid: int, mavlink1: bool = False) -> None:
        self.mav = MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.mavlink1 = mavlink1

    def encode(self, msg: MAVLinkMessage) -> bytes:
        buf = msg.pack(self.mav, force_mavlink1=self.mavlink1)
        self.mav.seq = (self.mav.seq + 1) % 256
        return bytes(buf)
