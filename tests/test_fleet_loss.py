"""Packet loss per vehicle on a shared link: two vehicles send to one UDP port, vehicle 2 with
every other sequence number missing, vehicle 1 with none. Each vehicle's `gcs status` and page
showed the link's sum (both about a third lost), so the vehicle on a clean route looked lossy."""

from __future__ import annotations

import asyncio
import socket

from live import wait_for

from gcs.mavlink.dialect import Encoder, mavlink
from gcs.runtime.fleet import Fleet
from gcs.runtime.link_stats import LinkStats
from gcs.runtime.station import StationConfig


def test_each_vehicle_on_a_shared_link_shows_its_own_packet_loss(udp_port):
    async def scenario():
        fleet = Fleet(StationConfig(connect=f"udpin:127.0.0.1:{udp_port}", estimate=False, request_streams=False))
        await fleet.start()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        clean, lossy = Encoder(1, 1), Encoder(2, 1)
        beat = mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, mavlink.MAV_STATE_STANDBY, 3
        )

        def lost(sysid: int) -> int:
            station = fleet.vehicle(sysid)
            return station.publish().link.stats.packets_lost if station is not None else 0

        try:
            async with asyncio.timeout(30):
                while len(fleet.vehicles()) < 2 or lost(2) < 40:
                    sock.sendto(clean.encode(beat), ("127.0.0.1", udp_port))
                    sock.sendto(lossy.encode(beat), ("127.0.0.1", udp_port))
                    lossy.mav.seq = (lossy.mav.seq + 1) % 256  # the one after it never arrives
                    await asyncio.sleep(0.02)
            await wait_for(lambda: lost(2) >= 40, 5, "vehicle 2's losses counted")
            return {s: fleet.vehicle(s).publish().link.stats for s in (1, 2)}  # type: ignore[union-attr]
        finally:
            sock.close()
            await fleet.stop()

    stats = asyncio.run(scenario())
    assert stats[1].packets_lost == 0 and stats[1].loss_fraction == 0.0
    assert stats[2].packets_lost >= 40 and 0.4 < stats[2].loss_fraction < 0.6


def test_each_vehicle_on_a_shared_link_counts_its_own_packets(udp_port):
    """Each vehicle's `packets` read the whole link's (both vehicles' heartbeats), beside its own
    loss: a count and a loss % that did not add up."""

    async def scenario():
        fleet = Fleet(StationConfig(connect=f"udpin:127.0.0.1:{udp_port}", estimate=False, request_streams=False))
        await fleet.start()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        beat = mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, mavlink.MAV_STATE_STANDBY, 3
        )
        try:
            for sysid in (1, 2):  # vehicle 2 first heard after vehicle 1's 30 heartbeats
                encoder = Encoder(sysid, 1)
                for _ in range(30):
                    sock.sendto(encoder.encode(beat), ("127.0.0.1", udp_port))
                    await asyncio.sleep(0.01)
            await wait_for(lambda: fleet.vehicle(2) is not None and fleet.vehicle(2).publish().link.stats.packets >= 30,  # type: ignore[union-attr]
                           10, "vehicle 2's 30 heartbeats")  # fmt: skip
            return {s: fleet.vehicle(s).publish().link.stats.packets for s in (1, 2)}  # type: ignore[union-attr]
        finally:
            sock.close()
            await fleet.stop()

    packets = asyncio.run(scenario())
    assert 28 <= packets[1] <= 30 and packets[2] == 30  # of the link's 60 (the first may go before its socket opens)


def test_a_ground_stations_heartbeats_are_not_counted_as_a_vehicles_packets(udp_port):
    """Messages from a system that is no vehicle (another ground station, sysid 255; a radio's
    RADIO_STATUS) reach every vehicle on the link, and were counted as each one's packets, beside a
    loss counted over its own: 30 heartbeats of vehicle 2 with 30 of a GCS read 60 packets, and its
    loss % half what it was."""

    async def scenario():
        fleet = Fleet(StationConfig(connect=f"udpin:127.0.0.1:{udp_port}", estimate=False, request_streams=False))
        await fleet.start()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        beat = mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, mavlink.MAV_STATE_STANDBY, 3
        )
        gcs_beat = mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE, 3
        )
        vehicle, other_gcs = Encoder(2, 1), Encoder(255, 190)
        try:
            await wait_for(lambda: fleet.links[0].is_open, 10, "the station's socket")
            for _ in range(30):
                sock.sendto(vehicle.encode(beat), ("127.0.0.1", udp_port))
                vehicle.mav.seq = (vehicle.mav.seq + 1) % 256  # the one after it never arrives
                sock.sendto(other_gcs.encode(gcs_beat), ("127.0.0.1", udp_port))
                await asyncio.sleep(0.01)

            def heartbeats() -> int:  # on the link, the vehicle's and the GCS's
                return fleet.links[0].stats.counts.get("HEARTBEAT", 0)

            await wait_for(lambda: heartbeats() >= 60, 10, "every heartbeat received")
            return fleet.vehicle(2).publish().link.stats  # type: ignore[union-attr]
        finally:
            sock.close()
            await fleet.stop()

    stats = asyncio.run(scenario())
    assert stats.packets == 30 and stats.packets_lost == 29
    assert stats.loss_fraction == round(29 / 59, 5)


def test_a_vehicles_packets_before_its_first_heartbeat_are_its_own(udp_port):
    """A stream that starts with 3 ATTITUDE before the first HEARTBEAT (a vehicle heard mid-stream)
    counted 30 packets of its 33 in `gcs status` and the page: the view counted from its bind, so
    the loss % (over sequence numbers the link saw from the first packet) was over too few. Vehicle
    2 also skips one sequence number among its first three."""

    async def scenario():
        fleet = Fleet(StationConfig(connect=f"udpin:127.0.0.1:{udp_port}", estimate=False, request_streams=False))
        await fleet.start()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        beat = mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, mavlink.MAV_STATE_STANDBY, 3
        )
        attitude = mavlink.MAVLink_attitude_message(1000, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0)
        try:
            await wait_for(lambda: fleet.links[0].is_open, 10, "the station's socket")
            for sysid in (1, 2):
                encoder = Encoder(sysid, 1)
                for i in range(3):
                    sock.sendto(encoder.encode(attitude), ("127.0.0.1", udp_port))
                    if sysid == 2 and i == 0:
                        encoder.mav.seq = (encoder.mav.seq + 1) % 256  # one lost before its heartbeat
                    await asyncio.sleep(0.01)
                for _ in range(30):
                    sock.sendto(encoder.encode(beat), ("127.0.0.1", udp_port))
                    await asyncio.sleep(0.01)
            await wait_for(lambda: fleet.links[0].stats.framing.packets >= 66, 10, "all 66 packets")
            return {s: fleet.vehicle(s).publish().link.stats for s in (1, 2)}  # type: ignore[union-attr]
        finally:
            sock.close()
            await fleet.stop()

    stats = asyncio.run(scenario())
    assert stats[1].packets == 33 and stats[1].packets_lost == 0
    assert stats[2].packets == 33 and stats[2].packets_lost == 1
    assert stats[2].loss_fraction == round(1 / 34, 5)


def test_a_vehicles_rates_are_its_own_systems(udp_port):
    """Another ground station's messages reach every vehicle on the link, and were counted in each
    vehicle's per-type counts and rates: a vehicle sending HEARTBEAT at 10 Hz beside a GCS at 10 Hz
    read HEARTBEAT 20 Hz in `gcs status`'s "other" line and the page, and the GCS's
    PARAM_REQUEST_LIST as the vehicle's."""

    async def scenario():
        fleet = Fleet(StationConfig(connect=f"udpin:127.0.0.1:{udp_port}", estimate=False, request_streams=False))
        await fleet.start()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        beat = mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, mavlink.MAV_STATE_STANDBY, 3
        )
        gcs_beat = mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE, 3
        )
        vehicle, other_gcs = Encoder(2, 1), Encoder(255, 190)

        def rates() -> dict[str, float]:
            station = fleet.vehicle(2)
            return {} if station is None else station.publish().link.stats.rates_hz

        try:
            await wait_for(lambda: fleet.links[0].is_open, 10, "the station's socket")
            async with asyncio.timeout(30):
                while fleet.links[0].stats.counts.get("HEARTBEAT", 0) < 80 or not rates():
                    sock.sendto(vehicle.encode(beat), ("127.0.0.1", udp_port))
                    sock.sendto(other_gcs.encode(gcs_beat), ("127.0.0.1", udp_port))
                    sock.sendto(
                        other_gcs.encode(mavlink.MAVLink_param_request_list_message(2, 1)), ("127.0.0.1", udp_port)
                    )
                    await asyncio.sleep(0.1)
            return fleet.vehicle(2).publish().link.stats  # type: ignore[union-attr]
        finally:
            sock.close()
            await fleet.stop()

    stats = asyncio.run(scenario())
    assert set(stats.counts) == {"HEARTBEAT"} and set(stats.rates_hz) == {"HEARTBEAT"}
    assert stats.rates_hz["HEARTBEAT"] < 12  # 10 Hz sent, give or take the loop's pace


def test_a_vehicles_rates_come_at_the_first_sample_after_it_is_identified():
    """A vehicle's rates start again from its own counts once it is identified (its history was
    of the link's): they came only at the second sample after, 1-2 s with no rates on the page,
    `gcs status` and `gcs demo`'s lines (a demo line then read without its ATTITUDE rate)."""
    stats = LinkStats()
    counts = {"ATTITUDE": 100}
    stats.follow(counts, 10.0)
    counts["ATTITUDE"] = 150
    stats.sample(11.0)
    assert stats.rates() == {"ATTITUDE": 50.0}
