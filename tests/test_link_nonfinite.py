"""The link refuses inf and NaN exactly where the station reads a number (gcs.mavlink.finite),
and passes MAVLink's legitimate NaN "unknown" values elsewhere. Real packets over a real UDP
socket into a real station that estimates (so reads every type checked here); what was refused is
counted per type, is a link event, and shows in `gcs status` (text and strict JSON)."""

from __future__ import annotations

import asyncio
import dataclasses
import math
import socket
import struct

from live import running_station, wait_for

from gcs.commands.status import format_report
from gcs.core import strict_json
from gcs.mavlink.dialect import Encoder, mavlink

NAN, INF = math.nan, math.inf


def attitude(roll=0.1, rollspeed=0.0):
    return mavlink.MAVLink_attitude_message(1000, roll, 0.0, 0.0, rollspeed, 0.0, 0.0)


def highres(xgyro=0.0, abs_pressure=1013.0):
    return mavlink.MAVLink_highres_imu_message(
        2_000_000, 0.0, 0.0, -9.8, xgyro, 0.0, 0.0, 0.2, 0.0, 0.4, abs_pressure, 0.0, 0.0, 20.0, 0
    )


def ahrs2(yaw=0.0, altitude=0.0):
    return mavlink.MAVLink_ahrs2_message(0.0, 0.0, yaw, altitude, 0, 0)


def simstate(pitch=0.0):
    return mavlink.MAVLink_simstate_message(0.0, pitch, 0.0, 0.0, 0.0, -9.8, 0.0, 0.0, 0.0, 0, 0)


def param(value: float, param_type: int):
    return mavlink.MAVLink_param_value_message(b"TEST_PARAM", value, param_type, 10, 1)


#: A PX4 INT32 parameter, bytewise-encoded: its integer's bytes read as a float are a NaN.
INT32_NAN_BITS = struct.unpack("<f", struct.pack("<i", 0x7FC00001))[0]

REFUSED = [
    attitude(roll=NAN),
    highres(xgyro=INF),
    ahrs2(yaw=-INF),
    simstate(pitch=NAN),
    param(NAN, mavlink.MAV_PARAM_TYPE_REAL32),
]
PASSED = [
    attitude(rollspeed=NAN),  # rates the station does not read
    highres(abs_pressure=NAN),  # HIGHRES_IMU pressure unknown
    ahrs2(altitude=NAN),  # AHRS2 altitude unknown
    param(INT32_NAN_BITS, mavlink.MAV_PARAM_TYPE_INT32),
    mavlink.MAVLink_command_long_message(1, 1, 400, 0, NAN, NAN, NAN, NAN, NAN, NAN, NAN),  # "unchanged" params
]


def test_non_finite_values_are_refused_only_where_the_station_reads_them(udp_port):
    snapshot, published = asyncio.run(scenario(udp_port))
    stats = snapshot.link.stats
    assert stats.nonfinite_rejected == {"AHRS2": 1, "ATTITUDE": 1, "HIGHRES_IMU": 1, "PARAM_VALUE": 1, "SIMSTATE": 1}
    assert sorted(published) == sorted(m.get_type() for m in PASSED)  # the refused went nowhere
    notes = [e.detail for e in snapshot.link.events if e.kind == "rejected"]
    assert "ATTITUDE with non-finite roll (counted, not used)" in notes and len(notes) == 5
    report = format_report(snapshot)
    assert "rejected   non-finite values: AHRS2 1, ATTITUDE 1, HIGHRES_IMU 1, PARAM_VALUE 1, SIMSTATE 1" in report
    assert "kernel drops 0" in report
    status = strict_json.loads(strict_json.dumps(dataclasses.asdict(snapshot), indent=2))  # as gcs status --json
    assert status["link"]["stats"]["nonfinite_rejected"]["PARAM_VALUE"] == 1


async def scenario(udp_port: int):
    async with running_station(f"udpin:127.0.0.1:{udp_port}", request_streams=False) as station:
        sub = station.bus.subscribe("test", maxlen=100)
        await wait_for(lambda: station.link.is_open, 10, "the UDP socket")
        # the estimation reads them (the link checks what a part reads by name)
        await wait_for(lambda: all(station.bus.wants(t) for t in ("HIGHRES_IMU", "AHRS2", "SIMSTATE")), 10, "readers")
        encoder = Encoder(1, 1)
        sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        for msg in [*REFUSED, *PASSED]:
            sender.sendto(encoder.encode(msg), ("127.0.0.1", udp_port))
        sender.close()
        count = len(REFUSED) + len(PASSED)
        await wait_for(lambda: station.link.stats.framing.packets == count, 10, "every packet decoded")
        published = [m.type for m in sub.drain()]
        return station.publish(), published
