"""The station's decode builds the very object pymavlink's `MAVLink.decode` builds, for every
message type of the dialect: MAVLink 1 and 2, payloads with their trailing zeros dropped, signed
packets, random field values (NaN and inf included)."""

from __future__ import annotations

import math
import random

import pytest
from fastcrc import crc16

from gcs.mavlink.decoding import decode
from gcs.mavlink.dialect import MAVLink, mavlink


def packet(msgid: int, payload: bytes, *, v1: bool = False, signed: bool = False, seq: int = 7) -> bytes:
    cls = mavlink.mavlink_map[msgid]
    if v1:
        head = bytes([0xFE, len(payload), seq, 42, 17, msgid])
    else:
        flags = 1 if signed else 0
        head = bytes([0xFD, len(payload), flags, 0, seq, 42, 17, msgid & 0xFF, msgid >> 8 & 0xFF, msgid >> 16])
    crc = crc16.mcrf4xx(bytes([cls.crc_extra]), crc16.mcrf4xx(head[1:] + payload, 0xFFFF))
    return head + payload + crc.to_bytes(2, "little") + (bytes(range(13)) if signed else b"")


def comparable(value):
    if isinstance(value, float) and math.isnan(value):
        return "nan"
    if isinstance(value, list):
        return [comparable(v) for v in value]
    if isinstance(value, mavlink.MAVLink_header):
        return vars(value)
    return value


def state(msg) -> tuple[type, dict]:
    return type(msg), {k: comparable(v) for k, v in vars(msg).items()}


@pytest.mark.parametrize("seed", [1, 2])
def test_every_type_decodes_to_the_object_pymavlink_builds(seed):
    rng = random.Random(seed)
    pymavlink = MAVLink(None)
    checked = 0
    for msgid, cls in mavlink.mavlink_map.items():
        size = cls.unpacker.size
        payload = rng.randbytes(size)
        variants = [packet(msgid, payload), packet(msgid, payload, signed=True)]
        variants.append(packet(msgid, payload[: rng.randint(1, size)].rstrip(b"\0") or b"\1"))  # truncated
        if msgid < 256:
            variants.append(packet(msgid, payload, v1=True))
        for p in variants:
            assert state(decode(p)) == state(pymavlink.decode(bytearray(p))), (cls.msgname, p.hex())
            checked += 1
    assert checked > 3 * len(mavlink.mavlink_map)
