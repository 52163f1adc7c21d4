"""The IMU messages read straight from their packet's payload, without pymavlink's message object.

HIGHRES_IMU, RAW_IMU and SCALED_IMU* are the bulk of a stream, and the estimation reads only their
time and nine axes. One precompiled struct per type unpacks those from the payload of a packet the
framing has checked (gcs.mavlink.framing); a zero-trimmed MAVLink 2 payload is padded with zeros
first, as pymavlink pads it. The struct codes are pymavlink's own (the type's leading fields in
wire order), so the values are the ones pymavlink's message would hold
(tests/test_imu_packets.py compares the samples on real streams).
"""

from __future__ import annotations

import struct
from typing import NamedTuple

from gcs.core.samples import ms_to_s, usec_to_s
from gcs.mavlink.dialect import MARKER_V1, mavlink

#: The nine axes every IMU message carries after its time field, in wire order.
IMU_AXES = ("xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro", "xmag", "ymag", "zmag")


class ImuPacket(NamedTuple):
    """An IMU message's type, source system, vehicle time (s since boot) and `IMU_AXES` values in
    the message's own units. `get_type` and `get_srcSystem` answer as pymavlink's message does, so
    the sampler (gcs.mavlink.sampling) routes it as it routes the decoded message. (A NamedTuple:
    built once per IMU message, it costs a third of a frozen dataclass.)"""

    type: str
    sysid: int
    t: float
    axes: tuple[float, ...]

    def get_type(self) -> str:
        return self.type

    def get_srcSystem(self) -> int:
        return self.sysid


def _layout(name: str) -> tuple[struct.Struct, bool]:
    """The struct of the type's leading fields (pymavlink's codes) and whether its time is in µs."""
    cls = next(c for c in mavlink.mavlink_map.values() if c.msgname == name)
    time_field = cls.ordered_fieldnames[0]
    if tuple(cls.ordered_fieldnames[1:10]) != IMU_AXES or time_field not in ("time_usec", "time_boot_ms"):
        raise ValueError(f"{name}: unexpected field order {cls.ordered_fieldnames}")
    codes = cls.unpacker.format.lstrip("<")
    if len(codes) != len(cls.ordered_fieldnames):  # one code per field, no counts
        raise ValueError(f"{name}: unexpected format {cls.unpacker.format}")
    return struct.Struct("<" + codes[:10]), time_field == "time_usec"


#: type → (struct of its time and axes, time in µs rather than ms)
_LAYOUTS: dict[str, tuple[struct.Struct, bool]] = {
    name: _layout(name) for name in ("HIGHRES_IMU", "RAW_IMU", "SCALED_IMU", "SCALED_IMU2", "SCALED_IMU3")
}
#: The types read this way.
IMU_PACKET_TYPES = frozenset(_LAYOUTS)


def imu_packet(packet: bytes, msg_type: str, sysid: int) -> ImuPacket:
    """The IMU packet of an intact packet (as the framing gave it) of one of `IMU_PACKET_TYPES`."""
    unpacker, usec = _LAYOUTS[msg_type]
    start = 6 if packet[0] == MARKER_V1 else 10
    plen = packet[1]
    if plen >= unpacker.size:
        values = unpacker.unpack_from(packet, start)
    else:  # MAVLink 2 drops trailing zeros: pad as pymavlink does
        values = unpacker.unpack(packet[start : start + plen] + bytes(unpacker.size - plen))
    time = values[0]
    return ImuPacket(msg_type, sysid, usec_to_s(time) if usec else ms_to_s(time), values[1:])
