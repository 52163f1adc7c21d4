"""The link reads the IMU messages from their bytes (gcs.mavlink.imu_packets) instead of building
pymavlink's message: the estimation inputs must be bit for bit the ones pymavlink's own decode
gives, on real streams (the ArduCopter SITL tlog in MAVLink 2 with its zero-trimmed payloads, the
ArduPlane tlog in MAVLink 1, the serve bench's PX4-like stream), on damaged bytes, on payloads
trimmed into the axes themselves, and with non-finite values (the same rejection, the same field)."""

from __future__ import annotations

import asyncio
import math
import random
from collections import Counter
from operator import attrgetter

import pytest
from exact import bits
from fastcrc import crc16

from bench.serve_cpu import packets as serve_stream
from gcs.mavlink.dialect import Encoder, MAVLink, mavlink
from gcs.mavlink.finite import nonfinite_axis, nonfinite_field
from gcs.mavlink.imu_packets import IMU_AXES, IMU_PACKET_TYPES, imu_packet
from gcs.mavlink.sampling import IMU_TYPES, INPUT_TYPES, MessageInputs
from gcs.mavlink.tlog import read_tlog_records
from gcs.runtime.bus import Message
from gcs.runtime.link import Link


def pymavlink_message(raw: bytes):
    """pymavlink's own decode, independent of the station's (gcs.mavlink.decoding)."""
    return MAVLink(None).decode(bytearray(raw))


def through_link(chunks: list[bytes], address: str = "udpin:127.0.0.1:9") -> tuple[Link, list[Message]]:
    """The chunks through a real link's receive path, to the estimation's subscription."""

    async def run() -> tuple[Link, list[Message]]:
        link = Link(address)
        sub = link.bus.subscribe("estimation", types=INPUT_TYPES, maxlen=1_000_000)
        items: list[Message] = []
        for chunk in chunks:
            link._on_data(chunk)
            items += sub.drain()
        return link, items

    return asyncio.run(run())


def assert_same_inputs(items: list[Message]) -> int:
    """The estimation inputs from what the link delivered equal those from pymavlink's messages of
    the same packets, message by message; returns how many IMU messages went the lean way."""
    lean, reference = MessageInputs(), MessageInputs()
    lean_imu = 0
    for k, item in enumerate(items):
        if item.type in IMU_PACKET_TYPES:
            assert item.imu is not None and not item.decoded  # read from the bytes, no pymavlink object
            lean_imu += 1
        wall = 1.7e9 + k * 0.01
        got = lean.feed(item.reading, wall)
        want = reference.feed(pymavlink_message(item.raw), wall)
        assert [bits(x) for x in got] == [bits(x) for x in want], (k, item.type, got, want)
    assert bits(lean.sampler.clock.latest) == bits(reference.sampler.clock.latest)
    assert (lean.sampler.imu_type, lean.declination_source) == (
        reference.sampler.imu_type,
        reference.declination_source,
    )
    return lean_imu


@pytest.mark.parametrize(
    ("name", "marker", "imu_types"),
    [
        ("arducopter-sitl-hop.tlog", 0xFD, {"RAW_IMU", "SCALED_IMU2", "SCALED_IMU3"}),
        ("arduplane-sitl-vtol.tlog", 0xFE, {"RAW_IMU", "SCALED_IMU2"}),
    ],
)
def test_a_real_tlog_gives_the_same_inputs_as_pymavlink(logs_dir, name, marker, imu_types):
    records = [packet for _, packet in read_tlog_records(logs_dir / name)]
    assert Counter(p[0] for p in records).most_common(1)[0][0] == marker  # MAVLink 2 / MAVLink 1
    intact_imu = Counter(pymavlink_message(p).get_type() for p in records if p[0] in (0xFD, 0xFE))
    link, items = through_link(records)
    lean = assert_same_inputs(items)
    assert {t for t in IMU_PACKET_TYPES if intact_imu[t]} == imu_types
    assert lean == sum(intact_imu[t] for t in IMU_PACKET_TYPES) > 1000
    assert {t: link.stats.counts.get(t) for t in imu_types} == {t: intact_imu[t] for t in imu_types}
    if marker == 0xFD:  # the SITL's MAVLink 2 trims trailing zeros: the padding is exercised
        trimmed = [i for i in items if i.imu is not None and i.raw[1] < pymavlink_message(i.raw).unpacker.size]
        assert trimmed


def test_the_serve_bench_stream_gives_the_same_inputs_as_pymavlink():
    datagrams = [packet for _, packet in serve_stream(1000, 3.0)]
    _, items = through_link(datagrams)
    types = Counter(pymavlink_message(p).get_type() for p in datagrams)
    highres = types["HIGHRES_IMU"]
    assert len(items) == sum(n for t, n in types.items() if t in INPUT_TYPES)
    assert assert_same_inputs(items) == highres > 2000


def test_damaged_bytes_give_the_same_inputs_as_pymavlink(logs_dir):
    """Flipped bytes, truncated packets and garbage in a byte stream (a serial or TCP link, read in
    arbitrary chunks): whatever the framing passes reads the same both ways."""
    rng = random.Random(17)
    damaged = bytearray()
    for k, (_, packet) in enumerate(read_tlog_records(logs_dir / "arducopter-sitl-hop.tlog")):
        if k > 6000:
            break
        cut = rng.random()
        if cut < 0.02:
            packet = packet[: rng.randrange(1, len(packet))]  # truncated
        elif cut < 0.04:
            packet = bytearray(packet)
            packet[rng.randrange(len(packet))] ^= 1 << rng.randrange(8)  # a flipped bit
        elif cut < 0.05:
            packet = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 40))) + packet  # garbage before
        damaged += packet
    data = bytes(damaged)
    chunks, i = [], 0
    while i < len(data):  # arbitrary reads, packets split anywhere
        step = rng.randrange(1, 300)
        chunks.append(data[i : i + step])
        i += step
    link, items = through_link(chunks, "tcp:127.0.0.1:9")
    assert link.stats.framing.crc_errors > 50
    assert assert_same_inputs(items) > 900


def trimmed(msg, version: int) -> bytes:
    return Encoder(3, 1, mavlink1=version == 1).encode(msg)


#: IMU messages whose MAVLink 2 payload loses its trailing zeros, some of them into the axes
IMU_MESSAGES = [
    mavlink.MAVLink_highres_imu_message(
        123456789, 0.5, -0.25, -9.81, 0.01, -0.02, 0.03, 0.2, -0.1, 0.4, 0, 0, 0, 0, 0, 0
    ),
    mavlink.MAVLink_highres_imu_message(5_000_000, 0.125, -0.5, -9.75, 1e-3, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0),
    mavlink.MAVLink_highres_imu_message(7, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0),
    mavlink.MAVLink_raw_imu_message(2_000_000, 10, -20, -1000, 1, 2, 3, 0, 0, 0, 0, 0),
    mavlink.MAVLink_raw_imu_message(2_000_000, 10, -20, -1000, 1, 2, 3, 200, -50, 400, 0, 0),
    mavlink.MAVLink_raw_imu_message(1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0),
    mavlink.MAVLink_scaled_imu_message(4321, 11, -21, -1001, 0, 0, 0, 0, 0, 0, 0),
    mavlink.MAVLink_scaled_imu2_message(4321, 11, -21, -1001, -1, -2, -3, 201, -51, 401, 0),
    mavlink.MAVLink_scaled_imu3_message(65535, -32768, 32767, 0, 0, 0, 0, 0, 0, 0, 0),
]


#: where the nine axes end in each type's payload (time_usec 8 or time_boot_ms 4, then 9 float or int16)
AXES_END = {
    "HIGHRES_IMU": 8 + 36,
    "RAW_IMU": 8 + 18,
    "SCALED_IMU": 4 + 18,
    "SCALED_IMU2": 4 + 18,
    "SCALED_IMU3": 4 + 18,
}


@pytest.mark.parametrize("version", [1, 2])
def test_trimmed_payloads_read_as_pymavlink_pads_them(version):
    raws = [trimmed(msg, version) for msg in IMU_MESSAGES]
    if version == 2:  # trimmed into the time and axes themselves, where the padding matters
        assert sum(raw[1] < AXES_END[msg.msgname] for raw, msg in zip(raws, IMU_MESSAGES, strict=True)) >= 4
    for raw in raws:
        ref = pymavlink_message(raw)
        got = imu_packet(raw, ref.get_type(), 3)
        assert bits(got.axes) == bits(attrgetter(*IMU_AXES)(ref)), ref
    link, items = through_link(raws)
    assert [item.type for item in items] == [msg.msgname for msg in IMU_MESSAGES]
    assert assert_same_inputs(items) == len(IMU_MESSAGES)


def test_a_signed_packet_reads_as_pymavlink_decodes_it():
    for msg in IMU_MESSAGES:
        plain = trimmed(msg, 2)
        head = bytearray(plain[:10])
        head[2] = 0x01  # signed: 13 bytes of signature follow the CRC
        body = bytes(head[1:]) + plain[10:-2]
        crc = crc16.mcrf4xx(bytes([msg.crc_extra]), crc16.mcrf4xx(body, 0xFFFF))
        raw = bytes(head) + plain[10:-2] + crc.to_bytes(2, "little") + bytes(range(13))
        ref = pymavlink_message(raw)
        assert ref.get_header().incompat_flags == 0x01
        got = imu_packet(raw, ref.get_type(), 3)
        assert bits(got.axes) == bits(attrgetter(*IMU_AXES)(ref)), ref


@pytest.mark.parametrize("version", [1, 2])
def test_a_non_finite_axis_is_refused_as_the_decoded_message_is(version):
    values = [0.5, -0.25, -9.81, 0.01, -0.02, 0.03, 0.2, -0.1, 0.4]
    raws = []
    for axis in range(9):
        for bad in (math.nan, math.inf, -math.inf):
            axes = list(values)
            axes[axis] = bad
            axes[(axis + 4) % 9] = math.inf if axis % 2 else axes[(axis + 4) % 9]  # a second one, sometimes
            msg = mavlink.MAVLink_highres_imu_message(1000 + axis, *axes, math.nan, 0, 0, 0, 0, 0)
            raws.append(trimmed(msg, version))
    for raw in raws:
        ref = pymavlink_message(raw)
        verdict = nonfinite_axis(imu_packet(raw, "HIGHRES_IMU", 3))
        assert verdict is not None and verdict == nonfinite_field(ref, "HIGHRES_IMU")
    good = trimmed(mavlink.MAVLink_highres_imu_message(2000, *values, math.nan, 0, 0, 0, 0, 0), version)
    assert nonfinite_axis(imu_packet(good, "HIGHRES_IMU", 3)) is None  # a NaN pressure is "unknown": used
    link, items = through_link([*raws, good])
    assert link.stats.nonfinite == {"HIGHRES_IMU": len(raws)}
    assert [item.raw for item in items] == [good]
    first = nonfinite_field(pymavlink_message(raws[0]), "HIGHRES_IMU")
    assert [e.detail for e in link.events if e.kind == "rejected"] == [
        f"HIGHRES_IMU with non-finite {first} (counted, not used)"
    ]


def test_the_packet_types_are_the_samplers_imu_types():
    assert frozenset(IMU_TYPES) == IMU_PACKET_TYPES


def test_another_reader_of_an_imu_type_still_gets_pymavlinks_message():
    raw = trimmed(IMU_MESSAGES[4], 2)

    async def run() -> Message:
        link = Link("udpin:127.0.0.1:9")
        sub = link.bus.subscribe("a tool", types=["RAW_IMU"])
        link._on_data(raw)
        return sub.drain()[0]

    item = asyncio.run(run())
    assert isinstance(item.msg, mavlink.MAVLink_raw_imu_message)
    ref = pymavlink_message(raw)
    assert {k: v for k, v in vars(item.msg).items() if not k.startswith("_")} == {
        k: v for k, v in vars(ref).items() if not k.startswith("_")
    }
