"""Another system on the link says "my SYSID_THISMAV is my own id", as a vehicle's echo does
when another ground station writes its system id: one such PARAM_VALUE from system 200 moved the
first vehicle's core (its page, recording, parameter writes) to system 200, shown "lost", and
the vehicle itself, still sending as system 1, became a second vehicle. The vehicle's next
heartbeat as system 1 shows the change was not its own: its core goes back to it."""

from __future__ import annotations

import asyncio
import socket

from live import wait_for

from gcs.mavlink.dialect import Encoder, mavlink
from gcs.runtime.fleet import Fleet
from gcs.runtime.link import LinkState
from gcs.runtime.station import StationConfig


def test_a_forged_system_id_echo_does_not_take_the_vehicles_core(udp_port):
    async def scenario():
        fleet = Fleet(StationConfig(connect=f"udpin:127.0.0.1:{udp_port}", estimate=False, request_streams=False))
        await fleet.start()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        vehicle, other = Encoder(1, 1), Encoder(200, 1)
        beat = mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, mavlink.MAV_STATE_STANDBY, 3
        )
        forged = mavlink.MAVLink_param_value_message(b"SYSID_THISMAV", 200, mavlink.MAV_PARAM_TYPE_INT8, 1000, 65535)
        core = fleet.first

        def events(kind: str) -> list[tuple[int, int]]:
            return [(e.data["old"], e.data["new"]) for e in core.events.recent if e.data.get("event") == kind]

        async def beating(until, what: str) -> None:
            async with asyncio.timeout(30):
                while not until():
                    sock.sendto(vehicle.encode(beat), ("127.0.0.1", udp_port))
                    await asyncio.sleep(0.05)

        try:
            await beating(lambda: core.link.state == LinkState.CONNECTED, "the vehicle")
            sock.sendto(other.encode(forged), ("127.0.0.1", udp_port))
            await wait_for(lambda: events("system id changed"), 10, "the forged echo taken")
            await beating(lambda: fleet.vehicle(1) is not None, "the vehicle heard again as system 1")
            return core, fleet.vehicle(1), [e.sysid for e in fleet.vehicles()], events("system id change undone")
        finally:
            sock.close()
            await fleet.stop()

    core, one, sysids, undone = asyncio.run(scenario())
    assert one is core, "the vehicle became a second vehicle; its first core follows system 200"
    assert sysids == [1] and core.link.target_system == 1
    assert undone == [(200, 1)]


def test_a_vehicle_switched_on_with_the_old_id_after_a_rename_is_another_vehicle(udp_port):
    """Renamed 1 → 7 (its echo, then its heartbeats as 7), the usual way to make room for a second
    airframe that keeps the default id 1: that airframe's heartbeats are another vehicle's, and
    must not take the renamed vehicle's core back to system 1."""

    async def scenario():
        fleet = Fleet(StationConfig(connect=f"udpin:127.0.0.1:{udp_port}", estimate=False, request_streams=False))
        await fleet.start()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        before, renamed, second = Encoder(1, 1), Encoder(7, 1), Encoder(1, 1)
        beat = mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, mavlink.MAV_STATE_STANDBY, 3
        )
        echo = mavlink.MAVLink_param_value_message(b"SYSID_THISMAV", 7, mavlink.MAV_PARAM_TYPE_INT8, 1000, 65535)
        core = fleet.first

        async def beating(encoder: Encoder, until) -> None:
            async with asyncio.timeout(30):
                while not until():
                    sock.sendto(encoder.encode(beat), ("127.0.0.1", udp_port))
                    await asyncio.sleep(0.05)

        try:
            await beating(before, lambda: core.link.state == LinkState.CONNECTED)
            sock.sendto(renamed.encode(echo), ("127.0.0.1", udp_port))
            await wait_for(lambda: core.link.target_system == 7, 10, "the rename followed")
            last = core.link.last_heartbeat or 0.0
            await beating(renamed, lambda: (core.link.last_heartbeat or 0.0) > last)  # its heartbeats as 7
            await beating(second, lambda: fleet.vehicle(1) is not None)
            undone = [e for e in core.events.recent if e.data.get("event") == "system id change undone"]
            return core, fleet.vehicle(7), fleet.vehicle(1), undone
        finally:
            sock.close()
            await fleet.stop()

    core, seven, one, undone = asyncio.run(scenario())
    assert seven is core, "the renamed vehicle's core was taken back to system 1 by another airframe"
    assert one is not core and undone == []
