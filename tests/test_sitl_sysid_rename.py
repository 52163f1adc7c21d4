"""A vehicle whose system id is written goes on as one vehicle under its new id, against the real
ArduCopter SITL (../shared/sitl). ArduPilot takes a new MAV_SYSID at once: the station then listed
a second vehicle (the new id) beside the first, which stayed "lost" for ever in /api/vehicles, the
page's vehicle list and `gcs status`, its page, estimation and recording stopped, whether the write
was the station's own (the page's parameter panel) or another ground station's on the vehicle's
second port (SERIAL1)."""

from __future__ import annotations

import asyncio

import pytest
from live import resend_until, wait_for
from test_sitl_copter import sitl  # noqa: F401  (the fixture)

from gcs.mavlink.decoding import decode
from gcs.mavlink.dialect import Encoder, mavlink
from gcs.mavlink.framing import MavlinkDecoder
from gcs.mavlink.params import param_name
from gcs.runtime.fleet import Fleet
from gcs.runtime.link import LinkState
from gcs.runtime.station import StationConfig

pytestmark = pytest.mark.slow


@pytest.mark.timeout(300)
def test_a_vehicle_given_a_new_system_id_stays_one_vehicle_under_it(sitl):  # noqa: F811
    async def scenario():
        fleet = Fleet(StationConfig(connect=f"tcp:127.0.0.1:{sitl}", estimate=False, heartbeat_timeout=2.0))
        await fleet.start()
        try:
            core = fleet.first
            assert await core.link.wait_connected(60)
            await core.params.set("MAV_SYSID", 7)  # as the page's parameter panel does
            beats = core.vehicle.heartbeats
            await wait_for(lambda: core.vehicle.heartbeats >= beats + 4, 30, "heartbeats as system 7")
            own = [(e.sysid, e.station.link.state) for e in fleet.vehicles()]

            # another ground station, on the vehicle's second port, gives it system id 9
            reader, writer = await asyncio.open_connection("127.0.0.1", sitl + 2)
            other = Encoder(254, 190)
            write = mavlink.MAVLink_param_set_message(7, 1, b"MAV_SYSID", 9, mavlink.MAV_PARAM_TYPE_INT8)
            await resend_until(lambda: core.link.target_system == 9, "id 9", lambda: writer.write(other.encode(write)))
            beats = core.vehicle.heartbeats
            await wait_for(lambda: core.vehicle.heartbeats >= beats + 4, 30, "heartbeats as system 9")
            writer.close()
            return own, [(e.sysid, e.station.link.state) for e in fleet.vehicles()], core, fleet.vehicle(9)
        finally:
            await fleet.stop()

    own, other, core, nine = asyncio.run(scenario())
    assert own == [(7, LinkState.CONNECTED)]
    assert other == [(9, LinkState.CONNECTED)]
    assert nine is core and core.params.table["MAV_SYSID"].value == 9
    changes = [(e.data["old"], e.data["new"]) for e in core.events.recent if e.data.get("event") == "system id changed"]
    assert changes == [(1, 7), (7, 9)]


@pytest.mark.timeout(300)
def test_a_system_id_written_by_another_station_with_its_echo_lost_is_followed(sitl, tcp_port):  # noqa: F811
    """Another ground station gives the vehicle system id 9 and the echo (PARAM_VALUE MAV_SYSID
    from system 9) is lost on the way to this station (a relay drops it): ArduCopter's packets
    as 9 go on with its sequence numbers, and the station listed a second vehicle beside the
    first, left lost."""

    async def relay(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        upstream_reader, upstream = await asyncio.open_connection("127.0.0.1", sitl)
        decoder = MavlinkDecoder()

        async def down() -> None:  # the vehicle's packets, the echo dropped
            while data := await upstream_reader.read(65536):
                for raw, name, sysid, _ in decoder.frames(data):
                    if not (name == "PARAM_VALUE" and sysid == 9 and param_name(decode(raw)) == "MAV_SYSID"):
                        writer.write(raw)

        async def up() -> None:
            while data := await reader.read(65536):
                upstream.write(data)

        try:
            await asyncio.gather(down(), up())
        finally:
            upstream.close()
            writer.close()

    async def scenario():
        server = await asyncio.start_server(relay, "127.0.0.1", tcp_port)
        fleet = Fleet(StationConfig(connect=f"tcp:127.0.0.1:{tcp_port}", estimate=False))
        await fleet.start()
        try:
            core = fleet.first
            assert await core.link.wait_connected(60)
            _, writer = await asyncio.open_connection("127.0.0.1", sitl + 2)  # SERIAL1: the other GCS
            other = Encoder(254, 190)
            write = mavlink.MAVLink_param_set_message(1, 1, b"MAV_SYSID", 9, mavlink.MAV_PARAM_TYPE_INT8)
            await resend_until(
                lambda: fleet.vehicle(9) is not None, "system 9", lambda: writer.write(other.encode(write))
            )
            beats = core.vehicle.heartbeats
            await wait_for(lambda: core.vehicle.heartbeats >= beats + 3, 30, "heartbeats as system 9")
            writer.close()
            return [(e.sysid, e.station.link.state) for e in fleet.vehicles()], core, fleet.vehicle(9)
        finally:
            await fleet.stop()
            server.close()

    vehicles, core, nine = asyncio.run(scenario())
    assert vehicles == [(9, LinkState.CONNECTED)] and nine is core
    changes = [(e.data["old"], e.data["new"]) for e in core.events.recent if e.data.get("event") == "system id changed"]
    assert changes == [(1, 9)]
