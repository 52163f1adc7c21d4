"""A lost link says why: the serial port that vanished (with its errno's words), the TCP peer
that closed, or the silence of a vehicle whose heartbeats stopped. The event said only
"connected -> lost" (the session's events.jsonl `{"old": "connected", "new": "lost"}`), and the
page and `gcs status` only "lost", whatever had gone. Real pseudo-terminal, UDP and TCP sockets
on loopback, the built-in simulator as the vehicle."""

from __future__ import annotations

import asyncio
import json

from live import running_sim, running_station, served_api, wait_for

from gcs.commands.status import format_report
from gcs.mavlink.dialect import Encoder, mavlink
from gcs.runtime.fleet import Fleet
from gcs.runtime.link import LinkState
from gcs.runtime.station import StationConfig
from gcs.sessions import layout


def test_a_vanished_serial_port_is_the_reason_of_the_loss_everywhere_it_is_shown(tmp_path):
    path = tmp_path / "ttyUSB-sim"

    async def scenario():
        async with running_station(
            str(path), heartbeat_timeout=1.5, sessions_dir=str(tmp_path / "rec"), record=True
        ) as station:
            link = station.link
            async with running_sim(f"pty:{path}", profile="apm25"):
                assert await link.wait_connected(10)
            await wait_for(lambda: station.snapshot.link.state == "lost", 10, "the link lost, published")
            async with served_api(station) as api:
                status = (await api.get("/api/status")).json()
                vehicles = (await api.get("/api/vehicles")).json()
            return station.recorder.session.folder, station.publish(), status, vehicles

    folder, snap, status, vehicles = asyncio.run(scenario())
    reasons = {f"{path} closed: the device is gone ({why})" for why in ("end of file", "Input/output error")}
    assert snap.link.lost_reason in reasons
    assert f"state lost ({snap.link.lost_reason})" in format_report(snap)
    assert status["link"]["lost_reason"] == snap.link.lost_reason
    assert vehicles[0]["lost_reason"] == snap.link.lost_reason
    assert f"connected -> lost: {snap.link.lost_reason}" in [e.detail for e in snap.link.events]
    lines = layout.session_file(folder, layout.EVENTS).read_text().splitlines()
    lost = [e for e in map(json.loads, lines) if e["kind"] == "link" and e.get("new") == "lost"]
    assert [e["reason"] for e in lost] == [snap.link.lost_reason]


def test_a_silent_udp_vehicle_is_lost_for_want_of_heartbeats(udp_port):
    async def scenario():
        async with running_station(f"udpin:127.0.0.1:{udp_port}", heartbeat_timeout=1.5) as station:
            async with running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk"):
                assert await station.link.wait_connected(10)
            await wait_for(lambda: station.link.state == LinkState.LOST, 10, "the link lost")
            return station.publish()

    snap = asyncio.run(scenario())
    assert snap.link.lost_reason == "no heartbeat for 1.5 s"
    assert snap.link.transport_open  # the socket is fine: the vehicle went quiet


def test_a_tcp_peer_that_closes_is_the_reason_of_the_loss(tcp_port):
    beat = mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3
    )

    async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        writer.write(b"".join(Encoder(1, 1).encode(beat) for _ in range(3)))
        await writer.drain()
        writer.close()  # and the listener with it: every redial is refused

    async def scenario():
        server = await asyncio.start_server(serve, "127.0.0.1", tcp_port)
        async with running_station(f"tcp:127.0.0.1:{tcp_port}", heartbeat_timeout=1.5, estimate=False) as station:
            assert await station.link.wait_connected(10)
            server.close()
            await wait_for(lambda: station.link.state == LinkState.LOST, 10, "the link lost")
            return station.publish()

    snap = asyncio.run(scenario())
    # (the close itself, or found by the station's next heartbeat: "Broken pipe")
    closed = f"tcp:127.0.0.1:{tcp_port} closed: the remote end closed the connection"
    assert snap.link.lost_reason in {closed, f"{closed} (Broken pipe)", f"{closed} (Connection reset by peer)"}


def test_a_serial_port_that_vanishes_is_lost_at_once_not_a_heartbeat_timeout_later(tmp_path):
    """The port's end is known when it comes: the page and `gcs status` showed the vehicle
    "connected" for `--heartbeat-timeout` s more (5 s here) with nothing able to arrive."""
    path = tmp_path / "ttyUSB-sim"

    async def scenario():
        fleet = Fleet(StationConfig(connect=str(path), heartbeat_timeout=5.0, estimate=False))
        await fleet.start()
        try:
            link = fleet.first.link  # the vehicle's view of the serial link, as gcs serve shows it
            async with running_sim(f"pty:{path}", profile="apm25"):
                assert await link.wait_connected(10)
            await wait_for(lambda: not link.is_open, 5, "the vanished port to be noticed")
            await wait_for(lambda: link.state == LinkState.LOST, 1.0, "the link lost with its port")
            return link.lost_reason, fleet.links[0].lost_reason
        finally:
            await fleet.stop()

    view, shared = asyncio.run(scenario())
    reasons = {f"{path} closed: the device is gone ({why})" for why in ("end of file", "Input/output error")}
    assert view in reasons and shared in reasons


def test_a_tcpin_client_that_hangs_up_is_the_reason_of_the_loss(tcp_port):
    """A vehicle (or a telemetry bridge) dialling the station's `tcpin:` listener hung up: the
    listener stays open, so the link waited for the heartbeat timeout and read "no heartbeat"."""
    beat = mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3
    )

    async def scenario():
        address = f"tcpin:127.0.0.1:{tcp_port}"
        async with running_station(address, heartbeat_timeout=5.0, estimate=False) as station:
            link = station.link
            await wait_for(lambda: link.is_open, 10, "the listener")
            _, writer = await asyncio.open_connection("127.0.0.1", tcp_port)
            writer.write(b"".join(Encoder(1, 1).encode(beat) for _ in range(3)))
            await writer.drain()
            assert await link.wait_connected(10)
            writer.close()
            await wait_for(lambda: link.state == LinkState.LOST, 1.0, "the link lost with its client")
            return address, link.lost_reason

    address, reason = asyncio.run(scenario())
    assert reason == f"{address}: the last client closed the connection"
