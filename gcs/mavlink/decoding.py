"""pymavlink's message object of a packet the framing has already checked, built in a fraction of
the time `MAVLink.decode` takes.

`MAVLink.decode` checks the header, the length and the CRC again, handles signing, unpacks the
payload, reorders the fields one by one and tests every field for a string, then builds the
object; the framing (gcs.mavlink.framing) has done the checks, so here a type's plan (made once)
unpacks, reorders with one C call, strips its strings and builds the same object with the same
attributes (tests/test_decoding.py compares them with pymavlink's on every type). Types with array
fields (a few, none of the station's inputs) are left to pymavlink's own decode.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from operator import itemgetter
from typing import Any, NamedTuple

from gcs.mavlink.dialect import MARKER_V1, MAVLink, MAVLinkMessage, mavlink

_SIGNED = mavlink.MAVLINK_IFLAG_SIGNED
_HEADER = mavlink.MAVLink_header
_PYMAVLINK = MAVLink(None)


class _Plan(NamedTuple):
    cls: type[MAVLinkMessage]
    unpacker: struct.Struct
    size: int
    fields: Callable[[tuple[Any, ...]], tuple[Any, ...]]  # the unpacked values, wire order → the class's argument order
    strings: tuple[int, ...]  # arguments that are char arrays (NUL-terminated bytes)


def _plan(cls: type[MAVLinkMessage]) -> _Plan | None:
    if any(length != 1 for length in cls.lengths):
        return None
    orders = cls.orders
    fields = itemgetter(*orders) if len(orders) > 1 else (lambda t, i=orders[0]: (t[i],))
    fmt = cls.unpacker.format
    codes = [c for c in fmt.lstrip("<") if not c.isdigit()]  # one code per field, in wire order
    strings = tuple(i for i, wire in enumerate(orders) if codes[wire] == "s")
    return _Plan(cls, cls.unpacker, cls.unpacker.size, fields, strings)


_PLANS: dict[int, _Plan | None] = {msgid: _plan(cls) for msgid, cls in mavlink.mavlink_map.items()}


def decode(packet: bytes) -> MAVLinkMessage:
    """The message of an intact packet of a known type (one the framing gave)."""
    if packet[0] == MARKER_V1:
        msgid, header_len, flags = packet[5], 6, 0
        seq, sysid, compid = packet[2], packet[3], packet[4]
    else:
        msgid, header_len, flags = packet[7] | (packet[8] << 8) | (packet[9] << 16), 10, packet[2]
        seq, sysid, compid = packet[4], packet[5], packet[6]
    plan = _PLANS[msgid]
    if plan is None:
        return _PYMAVLINK.decode(bytearray(packet))
    plen = packet[1]
    end = header_len + plen
    payload = packet[header_len:end]
    if plen < plan.size:  # MAVLink 2 drops trailing zeros
        payload += bytes(plan.size - plen)
    args = plan.fields(plan.unpacker.unpack(payload))
    if plan.strings:
        values = list(args)
        for i in plan.strings:
            values[i] = values[i].rstrip(b"\x00")
        args = tuple(values)
    msg = plan.cls(*args)
    msgbuf = bytearray(packet)
    tail = 2 + (13 if flags & _SIGNED else 0)
    msg._msgbuf = msgbuf
    msg._payload = msgbuf[6:-tail]  # (sic: pymavlink's own decode slices from 6 for MAVLink 2 too)
    msg._crc = packet[end] | (packet[end + 1] << 8)
    msg._header = _HEADER(msgid, flags, packet[3] if header_len == 10 else 0, plen, seq, sysid, compid)
    return msg
