"""COMMAND_ACKs that answer someone else's command: a vehicle on a shared link (a router, a mesh
radio) acks every ground station's commands, and its other components ack theirs. The station
took the first COMMAND_ACK of the command it waited on for its own answer, whoever sent it and
whoever it was for: a gimbal's or another ground station's DENIED refused streams the vehicle had
accepted. Here a small vehicle on a real UDP socket, as ArduPilot does (target_system/component
in its MAVLink 2 acks), sends both foreign refusals before its own acceptance of each
SET_MESSAGE_INTERVAL."""

from __future__ import annotations

import asyncio
import socket

from live import running_station, wait_for

from gcs.mavlink.dialect import Encoder, mavlink
from gcs.mavlink.framing import MavlinkDecoder
from gcs.runtime.streams import SET_MESSAGE_INTERVAL

SET_INTERVAL = mavlink.MAV_CMD_SET_MESSAGE_INTERVAL
DENIED, ACCEPTED = mavlink.MAV_RESULT_DENIED, mavlink.MAV_RESULT_ACCEPTED


class Vehicle:
    def __init__(self, port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        self.station = ("127.0.0.1", port)
        self.decoder = MavlinkDecoder()
        self.autopilot, self.gimbal = Encoder(1, 1), Encoder(1, mavlink.MAV_COMP_ID_GIMBAL)

    def ack(self, encoder: Encoder, result: int, to: tuple[int, int]) -> None:
        self.sock.sendto(
            encoder.encode(mavlink.MAVLink_command_ack_message(SET_INTERVAL, result, 0, 0, *to)), self.station
        )

    def step(self) -> None:
        beat = mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3
        )
        self.sock.sendto(self.autopilot.encode(beat), self.station)
        while True:
            try:
                data = self.sock.recv(65535)
            except BlockingIOError:
                return
            for msg in self.decoder.feed(data, final=True):
                if msg.get_type() == "COMMAND_LONG" and msg.command == SET_INTERVAL:
                    self.ack(self.gimbal, DENIED, (255, 190))  # the gimbal's, to a GCS asking it
                    self.ack(self.autopilot, DENIED, (254, 190))  # the autopilot's, to another GCS
                    self.ack(self.autopilot, ACCEPTED, (255, 190))  # ours


def test_acks_of_other_components_and_ground_stations_are_not_taken_for_ours(udp_port):
    async def scenario():
        vehicle = Vehicle(udp_port)

        async def fly() -> None:
            while True:
                vehicle.step()
                await asyncio.sleep(0.02)

        async with running_station(f"udpin:127.0.0.1:{udp_port}", estimate=False) as station:
            flying = asyncio.create_task(fly())
            try:
                await wait_for(lambda: station.streams.requested, 30, "the streams requested")
                return dict(station.streams.negotiated)
            finally:
                flying.cancel()
                vehicle.sock.close()

    negotiated = asyncio.run(scenario())
    assert negotiated and all(n.method == SET_MESSAGE_INTERVAL and n.reason is None for n in negotiated.values())
    assert all(n.accepted_hz == n.requested_hz for n in negotiated.values())
