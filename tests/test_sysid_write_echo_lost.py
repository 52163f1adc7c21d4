"""The station's own write of a vehicle's system id whose echo is lost on the radio: the vehicle
(a small one on a real UDP socket, behaving as ArduPilot does) takes the new id at once and its
next heartbeat comes as it. The fleet took that heartbeat for a new vehicle: a second core
started, the writing one went "lost" for ever, and the write read "no echo after 3 writes; the
value on the vehicle is unknown" (its retries went to the old id, which no longer answers). Now
the writing core follows its vehicle to the new id, and a retry there is echoed."""

from __future__ import annotations

import asyncio
import socket

from live import wait_for

from gcs.mavlink.dialect import Encoder, mavlink
from gcs.mavlink.framing import MavlinkDecoder
from gcs.mavlink.params import param_name
from gcs.runtime.fleet import Fleet
from gcs.runtime.link import LinkState
from gcs.runtime.station import StationConfig


class Vehicle:
    """ArduPilot's system id handling, in small: MAV_SYSID read, and written at once (the echo of
    the first write that changes it is lost)."""

    def __init__(self, port: int) -> None:
        self.sysid, self.echo_lost = 1, False
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        self.station = ("127.0.0.1", port)
        self.decoder = MavlinkDecoder()
        self.encoder = Encoder(1, 1)

    def send(self, msg) -> None:
        self.sock.sendto(self.encoder.encode(msg), self.station)

    def value(self) -> None:
        self.send(mavlink.MAVLink_param_value_message(b"MAV_SYSID", self.sysid, mavlink.MAV_PARAM_TYPE_INT8, 1, 0))

    def step(self) -> None:
        self.send(
            mavlink.MAVLink_heartbeat_message(
                mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3
            )
        )
        while True:
            try:
                data = self.sock.recv(65535)
            except BlockingIOError:
                return
            for msg in self.decoder.feed(data, final=True):
                kind = msg.get_type()
                if kind not in ("PARAM_REQUEST_READ", "PARAM_SET") or msg.target_system != self.sysid:
                    continue  # (the station's heartbeat, its AUTOPILOT_VERSION request)
                if param_name(msg) != "MAV_SYSID":
                    continue
                if kind == "PARAM_REQUEST_READ":
                    self.value()
                elif kind == "PARAM_SET":
                    if int(msg.param_value) != self.sysid and not self.echo_lost:
                        self.echo_lost = True  # the echo of the write that changes it never arrives
                        self.sysid = self.encoder.mav.srcSystem = int(msg.param_value)
                        continue
                    self.value()


def test_a_system_id_write_whose_echo_is_lost_follows_the_vehicle_to_its_new_id(udp_port):
    async def scenario():
        fleet = Fleet(StationConfig(connect=f"udpin:127.0.0.1:{udp_port}", estimate=False, request_streams=False))
        await fleet.start()
        vehicle = Vehicle(udp_port)

        async def fly() -> None:
            while True:
                vehicle.step()
                await asyncio.sleep(0.05)

        flying = asyncio.create_task(fly())
        try:
            core = fleet.first
            assert await core.link.wait_connected(10)
            stored = await core.params.set("MAV_SYSID", 7)
            beats = core.vehicle.heartbeats
            await wait_for(lambda: core.vehicle.heartbeats >= beats + 10, 10, "heartbeats as system 7")
            return stored.value, [(e.sysid, e.station.link.state) for e in fleet.vehicles()], vehicle.echo_lost
        finally:
            flying.cancel()
            vehicle.sock.close()
            await fleet.stop()

    stored, vehicles, echo_lost = asyncio.run(scenario())
    assert echo_lost and stored == 7
    assert vehicles == [(7, LinkState.CONNECTED)]
