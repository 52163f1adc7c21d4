"""A vehicle's system id changed by someone else with no echo heard (another ground station's
PARAM_SET of MAV_SYSID, its PARAM_VALUE lost on the radio): ArduPilot sends as the new id at once,
on the same channel, its packets' sequence numbers going on. The fleet took the new id's first
heartbeat for a new vehicle, and the old one stayed listed as lost beside it for ever. Now a new
system whose stream continues a vehicle's (gcs.runtime.sysid_change) is that vehicle renamed; two
vehicles that merely follow each other on the link stay two."""

from __future__ import annotations

import asyncio
import socket

from live import wait_for

from gcs.mavlink.dialect import Encoder, mavlink
from gcs.runtime.fleet import Fleet
from gcs.runtime.station import StationConfig

QUAD, PLANE = mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_TYPE_FIXED_WING


def _beat(mav_type: int) -> mavlink.MAVLink_heartbeat_message:
    return mavlink.MAVLink_heartbeat_message(mav_type, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3)


def _run(udp_port: int, second: str) -> tuple[list[int | None], list[str]]:
    """Vehicle 1 streams (a heartbeat and 9 ATTITUDE every 0.1 s), then `second` happens and system
    7 streams for 3 s; returns the fleet's vehicles and vehicle 7's fleet events."""

    async def scenario():
        fleet = Fleet(StationConfig(connect=f"udpin:127.0.0.1:{udp_port}", estimate=False, request_streams=False))
        await fleet.start()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        to = ("127.0.0.1", udp_port)
        one = Encoder(1, 1)

        def stream(encoder: Encoder, mav_type: int, packets: int, also: Encoder | None = None) -> list[bytes]:
            out = []
            for i in range(packets):
                msg = _beat(mav_type) if i % 10 == 0 else mavlink.MAVLink_attitude_message(i, 0.1, 0.2, 0.3, 0, 0, 0)
                out.append(encoder.encode(msg))
                if also is not None:
                    out.append(also.encode(msg))
            return out

        async def send(packets: list[bytes]) -> None:
            for packet in packets:
                sock.sendto(packet, to)
                await asyncio.sleep(0.01)

        try:
            await wait_for(lambda: fleet.links[0].is_open, 10, "the station's socket")
            await send(stream(one, QUAD, 40))
            await wait_for(lambda: fleet.vehicle(1) is not None, 10, "vehicle 1")
            if second == "renamed":  # the same channel: its sequence numbers go on
                one.mav.srcSystem = 7
                await send(stream(one, QUAD, 300))
            elif second == "another type":  # sequence numbers that happen to go on
                one.mav.srcSystem = 7
                await send(stream(one, PLANE, 300))
            elif second == "both on":  # vehicle 1 goes on beside system 7
                seven = Encoder(7, 1)
                seven.mav.seq = one.mav.seq
                await send(stream(seven, QUAD, 150, also=one))
            else:  # "fresh": another vehicle switched on as vehicle 1 goes silent
                await send(stream(Encoder(7, 1), QUAD, 300))
            await wait_for(lambda: fleet.vehicle(7) is not None, 10, "system 7 served")
            events = [e.data.get("event") for e in fleet.vehicle(7).events.recent if e.client == "fleet"]  # type: ignore[union-attr]
            return [e.sysid for e in fleet.vehicles()], events
        finally:
            sock.close()
            await fleet.stop()

    return asyncio.run(scenario())


def test_a_system_id_changed_elsewhere_is_followed(udp_port):
    vehicles, events = _run(udp_port, "renamed")
    assert vehicles == [7]
    assert "system id changed" in events


def test_a_vehicle_switched_on_as_another_goes_silent_is_another(udp_port):
    vehicles, _ = _run(udp_port, "fresh")
    assert vehicles == [1, 7]


def test_another_type_is_another_vehicle(udp_port):
    vehicles, _ = _run(udp_port, "another type")
    assert vehicles == [1, 7]


def test_a_vehicle_still_sending_is_not_renamed(udp_port):
    vehicles, _ = _run(udp_port, "both on")
    assert vehicles == [1, 7]
