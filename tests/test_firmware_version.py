"""The firmware version over real UDP against the simulator: the Pixhawk's AUTOPILOT_VERSION is
asked for at connect (MAV_CMD_REQUEST_MESSAGE) and shown in the snapshot and the recording's
metadata; the APM 2.5 has no AUTOPILOT_VERSION and is known by its STATUSTEXT banner."""

from __future__ import annotations

import asyncio
import shutil

from live import running_sim, running_station, wait_for

from gcs.mavlink.dialect import mavlink
from gcs.mavlink.firmware_version import banner_version, version_of
from gcs.runtime.station import Station, StationConfig
from gcs.sessions import layout
from gcs.sessions.sources import open_source


def version_message(flight_sw_version: int, custom: bytes):
    zeros = [0] * 8
    return mavlink.MAVLink_autopilot_version_message(0, flight_sw_version, 0, 0, 0, list(custom), zeros, zeros, 0, 0, 0)


def test_version_text_from_autopilot_version_and_from_banners():
    dev = version_message((4 << 24) | (7 << 16) | mavlink.FIRMWARE_VERSION_TYPE_DEV, b"51a3b691")
    assert version_of(dev) == "4.7.0-dev (51a3b691)"
    official = version_message((4 << 24) | (5 << 16) | (7 << 8) | mavlink.FIRMWARE_VERSION_TYPE_OFFICIAL, bytes(8))
    assert version_of(official) == "4.5.7"
    assert banner_version("ArduPlane V4.7.0-dev (51a3b691)") == "ArduPlane 4.7.0-dev (51a3b691)"
    assert banner_version("APM:Copter V3.2.1 (36b405fb)") == "APM:Copter 3.2.1 (36b405fb)"
    assert banner_version("EKF3 IMU0 initialised") is None
    assert banner_version("Requested rate for message ID 30 too fast. Increas") is None


def test_pixhawk_version_requested_at_connect_reaches_the_metadata(udp_port, tmp_path):
    async def scenario():
        async with (
            running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk") as sim,
            running_station(
                f"udpin:127.0.0.1:{udp_port}", estimate=False, sessions_dir=str(tmp_path), record=True
            ) as station,
        ):
            await wait_for(lambda: station.vehicle.firmware is not None, 20, "the firmware version")
            assert sim.received.get("COMMAND_LONG", 0) >= 1
            await wait_for(lambda: station.recorder.session is not None, 10, "a recording")

            def meta() -> dict:
                return layout.read_meta(station.recorder.session.folder)  # renamed once the vehicle is known

            await wait_for(
                lambda: meta().get("vehicle", {}).get("firmware") is not None, 15, "the firmware in meta.json"
            )
            return station.publish().vehicle.firmware, meta()

    firmware, meta = asyncio.run(scenario())
    assert firmware == "4.5.7"
    assert meta["vehicle"]["firmware"] == "4.5.7"
    assert meta["link"]["baud"] is None  # UDP has no baud rate (it read 57600)
    # the session's tlog alone, as another tool would keep it: the same version, from the
    # AUTOPILOT_VERSION it recorded (a bare tlog's firmware was unknown)
    (folder,) = [p for p in tmp_path.iterdir() if layout.is_session(p)]
    bare = shutil.copy(layout.session_file(folder, layout.TLOG), tmp_path / "flight.tlog")
    assert open_source(bare).meta["vehicle"]["firmware"] == "4.5.7"


def test_apm25_version_from_its_banner(udp_port):
    async def scenario():
        async with running_sim(f"udpout:127.0.0.1:{udp_port}", profile="apm25"):
            station = Station(StationConfig(connect=f"udpin:127.0.0.1:{udp_port}", estimate=False))
            acks = station.bus.subscribe("test-acks", types=["COMMAND_ACK"])  # before anything is sent
            answered: list[int] = []

            def version_request_answered() -> bool:
                answered.extend(m.msg.command for m in acks.drain())
                return mavlink.MAV_CMD_REQUEST_MESSAGE in answered

            await station.start()
            try:
                await wait_for(version_request_answered, 20, "the answer to the AUTOPILOT_VERSION request")
                # whatever the vehicle sent with its answer came before its next heartbeat
                heartbeats = station.vehicle.heartbeats
                await wait_for(lambda: station.vehicle.heartbeats > heartbeats, 10, "the next heartbeat")
                assert station.vehicle.firmware is None  # no AUTOPILOT_VERSION on an APM 2.5
                await station.params.download(60)
                return station.vehicle.firmware
            finally:
                await station.stop()

    assert asyncio.run(scenario()) == "APM:Copter 3.2.1 (36b405fb)"
