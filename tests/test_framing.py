"""The decoder against damage: garbage, truncated frames and bit flips between valid packets
are skipped and counted, and every intact packet after them still decodes."""

from __future__ import annotations

import random
import time

from gcs.mavlink.dialect import Encoder, mavlink
from gcs.mavlink.framing import MavlinkDecoder

STREAMS = 10_000
TIME_LIMIT_S = 120.0


def packet_pool() -> list[bytes]:
    """Valid packets of several types and sizes, in both protocol versions."""
    v1, v2 = Encoder(1, 1, mavlink1=True), Encoder(1, 1)
    messages = [
        mavlink.MAVLink_heartbeat_message(2, 3, 81, 0, 4, 3),
        mavlink.MAVLink_raw_imu_message(123456, 10, -20, -1000, 1, 2, 3, 200, -50, 400),
        mavlink.MAVLink_attitude_message(1000, 0.1, -0.2, 3.0, 0.01, 0.02, 0.03),
        mavlink.MAVLink_gps_raw_int_message(10**15, 3, 71234567, -1234567, 1500, 100, 100, 250, 9000, 12),
        mavlink.MAVLink_param_value_message(b"ATC_RAT_RLL_P", 0.135, 9, 700, 12),
        mavlink.MAVLink_ahrs2_message(0.1, 0.2, 0.3, 10.0, 71234567, -1234567),
        mavlink.MAVLink_statustext_message(6, b"PreArm: hello"),
    ]
    return [enc.encode(m) for m in messages for enc in (v1, v2)]


def mutated_stream(rng: random.Random, pool: list[bytes]) -> tuple[bytes, list[bytes]]:
    """A stream of valid packets with damage between them; returns (bytes, intact packets)."""
    parts: list[bytes] = []
    intact: list[bytes] = []
    for _ in range(rng.randint(3, 12)):
        damage = rng.random()
        if damage < 0.25:  # garbage, biased towards start-of-frame markers
            parts.append(bytes(rng.choice((0xFE, 0xFD, rng.getrandbits(8))) for _ in range(rng.randint(1, 40))))
        elif damage < 0.45:  # a truncated frame
            p = rng.choice(pool)
            parts.append(p[: rng.randint(1, len(p) - 1)])
        elif damage < 0.65:  # a frame with one bit flipped
            p = bytearray(rng.choice(pool))
            p[rng.randrange(len(p))] ^= 1 << rng.randrange(8)
            parts.append(bytes(p))
        p = rng.choice(pool)
        parts.append(p)
        intact.append(p)
    return b"".join(parts), intact


def is_subsequence(needles: list[bytes], haystack: list[bytes]) -> bool:
    it = iter(haystack)
    return all(any(n == h for h in it) for n in needles)


def decode_in_chunks(rng: random.Random, stream: bytes) -> tuple[list[bytes], MavlinkDecoder]:
    decoder = MavlinkDecoder()
    out: list[bytes] = []
    i = 0
    while i < len(stream):
        step = rng.randint(1, 64)
        out += [bytes(m.get_msgbuf()) for m in decoder.feed(stream[i : i + step])]
        i += step
    out += [bytes(m.get_msgbuf()) for m in decoder.feed(b"", final=True)]
    return out, decoder


def test_clean_stream_decodes_everything_in_any_chunking():
    rng = random.Random(7)
    pool = packet_pool()
    packets = [rng.choice(pool) for _ in range(500)]
    out, decoder = decode_in_chunks(rng, b"".join(packets))
    assert out == packets
    c = decoder.counters
    assert (c.crc_errors, c.malformed, c.bytes_skipped) == (0, 0, 0)
    assert c.mavlink1 + c.mavlink2 == 500 and c.mavlink1 > 0 and c.mavlink2 > 0


def test_ten_thousand_mutated_streams_keep_every_intact_packet():
    rng = random.Random(2026)
    pool = packet_pool()
    started = time.monotonic()
    damaged_bytes = 0
    for n in range(STREAMS):
        stream, intact = mutated_stream(rng, pool)
        out, decoder = decode_in_chunks(rng, stream)
        assert is_subsequence(intact, out), f"stream {n}: an intact packet was lost"
        extra_bytes = len(stream) - sum(len(p) for p in out)
        assert decoder.counters.bytes_skipped == extra_bytes, f"stream {n}: skipped bytes not counted"
        damaged_bytes += extra_bytes
        assert time.monotonic() - started < TIME_LIMIT_S, f"only {n} streams within {TIME_LIMIT_S} s"
    assert damaged_bytes > 0


def test_bit_flip_is_counted_as_crc_error_and_next_packet_survives():
    pool = packet_pool()
    bad = bytearray(pool[2])
    bad[12] ^= 0x10
    decoder = MavlinkDecoder()
    out = decoder.feed(bytes(bad) + pool[3], final=True)
    assert [bytes(m.get_msgbuf()) for m in out] == [pool[3]]
    assert decoder.counters.crc_errors >= 1


def test_sequence_gaps_are_counted_per_source():
    enc = Encoder(7, 1)
    packets = [enc.encode(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3)) for _ in range(10)]
    decoder = MavlinkDecoder()
    decoder.feed(b"".join(packets[:3] + packets[6:]))  # seq 3, 4, 5 missing
    assert decoder.counters.lost == {(7, 1): 3}


def test_a_restarted_sequence_takes_back_only_the_gaps_since_the_old_boots_last_clock():
    """A reboot behind an open port (gcs.runtime.vehicle: seen by the clock, after the fact): the
    jump to the new boot's numbers, counted lost, is taken back; a loss before the old boot's
    last clock reading stays counted, and so does another sender's."""
    heartbeat = mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3)
    old, other = Encoder(7, 1), Encoder(8, 1)
    packets = [old.encode(heartbeat) for _ in range(200)]
    decoder = MavlinkDecoder()
    decoder.feed(b"".join(packets[:3] + packets[6:150]) + other.encode(heartbeat))  # 3 lost
    other.encode(heartbeat)  # one of the other sender's lost
    decoder.feed(other.encode(heartbeat))
    last_clock = time.monotonic()  # the old boot's last clock reading: packet 149
    new = Encoder(7, 1)  # rebooted: numbers from 0, a jump from 149 counted as 106 lost
    decoder.feed(b"".join(new.encode(heartbeat) for _ in range(5)))
    assert decoder.counters.lost == {(7, 1): 3 + 106, (8, 1): 1}
    assert decoder.restart_sequence((7, 1), last_clock) == 106
    assert decoder.counters.lost == {(7, 1): 3, (8, 1): 1}
    assert decoder.restart_sequence((7, 1), last_clock) == 0  # taken back once
