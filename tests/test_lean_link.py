"""The lean link: every packet is framed, CRC-checked, counted, forwarded and recorded as the bytes
that arrived, but only the types some part of the station reads are decoded. Real packets over a
real UDP socket into a real station that estimates, records and forwards to a real UDP socket."""

from __future__ import annotations

import asyncio
import socket

from live import running_station, wait_for

from gcs.mavlink.dialect import Encoder, mavlink
from gcs.mavlink.tlog import read_tlog_records
from gcs.sessions import layout

#: types no part of the station reads: framed, counted, forwarded, recorded, never decoded
UNREAD = ("VFR_HUD", "SERVO_OUTPUT_RAW")


def stream() -> list[bytes]:
    enc = Encoder(1, 1)
    out = [enc.encode(mavlink.MAVLink_heartbeat_message(2, 3, 81, 0, 4, 3))]
    for k in range(20):
        out.append(enc.encode(mavlink.MAVLink_attitude_message(1000 + 10 * k, 0.1, -0.2, 0.3, 0.0, 0.0, 0.0)))
        out.append(enc.encode(mavlink.MAVLink_vfr_hud_message(12.0, 11.5, 90, 40, 100.0 + k, 0.5)))
        out.append(enc.encode(mavlink.MAVLink_servo_output_raw_message(1000 * k, 0, *[1500] * 8)))
    return out


def test_every_packet_is_counted_forwarded_and_recorded_but_only_read_types_are_decoded(udp_port, tmp_path):
    good = stream()
    damaged = bytearray(good[2])  # a VFR_HUD with one payload byte flipped: its CRC no longer matches
    damaged[12] ^= 0x40
    out_rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    out_rx.bind(("127.0.0.1", 0))
    out_rx.settimeout(10)
    out_port = out_rx.getsockname()[1]

    async def scenario():
        config = {
            "sessions_dir": str(tmp_path),
            "record": True,
            "outputs": [f"udpout:127.0.0.1:{out_port}"],
            "request_streams": False,
        }
        async with running_station(f"udpin:127.0.0.1:{udp_port}", **config) as station:
            everything = station.bus.subscribe("test", maxlen=1000)  # every type, as the recorder
            await wait_for(lambda: station.link.is_open and station.bus.wants("ATTITUDE"), 10, "the socket, readers")
            sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            for packet in [good[0], bytes(damaged), *good[1:]]:
                sender.sendto(packet, ("127.0.0.1", udp_port))
            sender.close()
            await wait_for(lambda: station.link.stats.framing.packets == len(good), 10, "every packet")
            await wait_for(lambda: station.recorder.packets["received"] == len(good), 10, "every packet recorded")
            snapshot = station.link.snapshot()
            items = everything.drain()
        return snapshot, items

    snapshot, items = asyncio.run(scenario())
    forwarded = [out_rx.recv(1000) for _ in good]
    out_rx.close()

    assert snapshot.stats.crc_errors == 1
    assert snapshot.stats.counts == {"ATTITUDE": 20, "HEARTBEAT": 1, "SERVO_OUTPUT_RAW": 20, "VFR_HUD": 20}
    assert forwarded == good  # the damaged one is not passed on
    assert [item.raw for item in items] == good
    # the estimation and the vehicle state read ATTITUDE and HEARTBEAT: decoded by the link;
    # nobody asked for the others by name and the recorder took their bytes
    assert all(item.decoded for item in items if item.type in ("ATTITUDE", "HEARTBEAT"))
    assert not any(item.decoded for item in items if item.type in UNREAD)
    assert items[2].msg.airspeed == 12.0  # still there when asked for

    (session,) = [p for p in tmp_path.iterdir() if layout.is_session(p)]
    recorded = [packet for _, packet in read_tlog_records(session / layout.TLOG)]
    received = [p for p in recorded if p in good]  # (the station's own heartbeats are recorded too)
    assert received == good
