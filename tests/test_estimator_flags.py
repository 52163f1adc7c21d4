"""The vehicle panel's EKF row names the autopilot estimator's flags from what each firmware
sends: ArduPilot's EKF_STATUS_REPORT, PX4's ESTIMATOR_STATUS. The two enums share bits 1-512 and
differ at 1024: "uninitialised" in ArduPilot's, a GPS glitch in PX4's. Real packets over a real
UDP socket into a running station; the PX4 simulator's stream asked for and received at 1 Hz."""

from __future__ import annotations

import asyncio
import socket
from contextlib import closing

from live import running_sim, running_station, wait_for

from gcs.mavlink.dialect import Encoder, MAVLinkMessage, mavlink
from gcs.runtime.snapshots import VehicleSnapshot


def heartbeat(autopilot: int) -> MAVLinkMessage:
    return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, autopilot, 0, 0, mavlink.MAV_STATE_STANDBY, 3)


def test_each_firmware_flag_is_named_by_its_own_enum(udp_port: int) -> None:
    bit_1024 = 1024
    px4 = mavlink.MAVLink_estimator_status_message(
        1_000_000, mavlink.ESTIMATOR_ATTITUDE | bit_1024, 0, 0, 0, 0, 0, 0, 0, 0
    )
    ardupilot = mavlink.MAVLink_ekf_status_report_message(mavlink.EKF_ATTITUDE | bit_1024, 0.25, 0.5, 0.125, 0.375, 0.0)

    async def scenario() -> tuple[VehicleSnapshot, VehicleSnapshot]:
        async with running_station(f"udpin:127.0.0.1:{udp_port}", request_streams=False, estimate=False) as station:
            encoder = Encoder(1, 1)
            with closing(socket.socket(socket.AF_INET, socket.SOCK_DGRAM)) as sock:

                def send(*messages: MAVLinkMessage) -> None:
                    for msg in messages:
                        sock.sendto(encoder.encode(msg), ("127.0.0.1", udp_port))

                await wait_for(lambda: station.link.is_open, 10, "the UDP socket")
                send(heartbeat(mavlink.MAV_AUTOPILOT_PX4), px4)
                await wait_for(lambda: station.vehicle.ekf_flags, 10, "PX4's flags in the state")
                from_px4 = station.publish().vehicle
                send(heartbeat(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA), ardupilot)
                await wait_for(lambda: station.vehicle.ekf_variance_max is not None, 10, "ArduPilot's report")
                return from_px4, station.publish().vehicle

    from_px4, from_ardupilot = asyncio.run(scenario())
    assert (from_px4.ekf_flags, from_px4.ekf_variance_max) == (["ATTITUDE", "GPS_GLITCH"], None)
    assert (from_ardupilot.ekf_flags, from_ardupilot.ekf_variance_max) == (["ATTITUDE", "UNINITIALIZED"], 0.5)


def test_px4_estimator_status_is_asked_at_1_hz_and_fills_the_ekf_row(udp_port: int) -> None:
    """PX4 streams ESTIMATOR_STATUS at 0.5 Hz by default (mavlink_main.cpp, normal mode); gcs asks
    for 1 Hz, as it does EKF_STATUS_REPORT of an ArduPilot, and the vehicle accepts it."""

    async def scenario():
        async with (
            running_sim(f"udpout:127.0.0.1:{udp_port}", profile="px4"),
            running_station(f"udpin:127.0.0.1:{udp_port}", estimate=False) as station,
        ):
            station.streams.check_interval = 0.25

            def accepted() -> bool:
                row = station.publish().streams.messages.get("ESTIMATOR_STATUS")
                return row is not None and bool(row.accepted_hz) and row.achieved_hz > 0.75

            await wait_for(accepted, 60, "ESTIMATOR_STATUS at 1 Hz")
            snapshot = station.publish()
            return snapshot.streams.messages["ESTIMATOR_STATUS"], snapshot.vehicle.ekf_flags

    row, flags = asyncio.run(scenario())
    assert (row.method, row.ack, row.accepted_hz) == ("SET_MESSAGE_INTERVAL", "ACCEPTED", 1.0), row
    assert {"ATTITUDE", "VELOCITY_HORIZ", "POS_HORIZ_ABS"} <= set(flags), flags
