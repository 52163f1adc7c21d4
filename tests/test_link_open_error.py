"""A link that cannot open says why where the person looks: the page's warning, /api/status and
`gcs status`'s link line. The reason ("cannot open tcp:127.0.0.1:5760: Connection refused") was
only one of the link's events, which the page does not show: it read "link waiting: no fresh
data", the same as a vehicle that has not sent its first heartbeat yet. A real TCP port on
loopback, nobody listening, then a vehicle."""

from __future__ import annotations

import asyncio
import socket

from live import served_api, wait_for

from gcs.commands.status import format_report
from gcs.mavlink.dialect import Encoder, mavlink
from gcs.runtime.fleet import Fleet
from gcs.runtime.station import StationConfig


def test_a_link_that_cannot_open_names_why_until_it_opens(tcp_port):
    address = f"tcp:127.0.0.1:{tcp_port}"
    beat = mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3
    )

    async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        writer.write(Encoder(1, 1).encode(beat))
        await writer.drain()
        await reader.read()  # open until the station closes it

    async def scenario():
        fleet = Fleet(StationConfig(connect=address, estimate=False))
        await fleet.start()
        try:
            core = fleet.first
            await wait_for(lambda: core.publish().link.open_error is not None, 10, "the refused dial")
            refused = core.publish()
            async with served_api(core) as api:
                status = (await api.get("/api/status")).json()
            server = await asyncio.start_server(serve, "127.0.0.1", tcp_port)
            async with server:
                assert await core.link.wait_connected(15)
                opened = core.publish()
            return refused, status, opened
        finally:
            await fleet.stop()

    refused, status, opened = asyncio.run(scenario())
    why = f"cannot open {address}: Connection refused"
    assert refused.link.open_error == why
    assert status["link"]["open_error"] == why
    assert f"state waiting ({why}; retrying)" in format_report(refused)
    assert opened.link.open_error is None


def test_a_tcp_host_that_drops_the_dial_is_given_up_on_and_redialled():
    """A `tcp:` host that never answers the dial (a firewall dropping SYNs, a board off behind a
    router): the open waited for the kernel's ~2 min of SYN retries, with no reason shown and no
    retry. Here a real listener on loopback whose accept queue is full drops every SYN; once it
    has room, the redial opens."""
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(0)
    port = listener.getsockname()[1]
    filler = socket.create_connection(("127.0.0.1", port))  # the queue's one place: later SYNs dropped
    address = f"tcp:127.0.0.1:{port}"

    async def scenario():
        fleet = Fleet(StationConfig(connect=address, estimate=False))
        await fleet.start()
        try:
            core = fleet.first
            await wait_for(lambda: core.publish().link.open_error is not None, 10, "the dial given up")
            dropped = core.publish()
            listener.accept()[0].close()  # room in the queue: the next dial is answered
            await wait_for(lambda: fleet.links[0].is_open, 15, "the redial")
            return dropped, core.publish()
        finally:
            await fleet.stop()

    try:
        dropped, opened = asyncio.run(scenario())
    finally:
        filler.close()
        listener.close()
    why = f"cannot open {address}: no answer within 5 s (connection timed out)"
    assert dropped.link.open_error == why
    assert f"state waiting ({why}; retrying)" in format_report(dropped)
    assert opened.link.open_error is None
