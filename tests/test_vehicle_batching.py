"""The vehicle state takes what its subscription gathered once every OBSERVE_INTERVAL
(gcs.runtime.vehicle): the batching saves the loop a wake-up per message and must cost the user
nothing else. Real packets over a real UDP socket into a running station: after a burst many
batches long, every message has reached the state in the order sent (counters, the last values,
the STATUSTEXT list and event log, a reboot inside the burst counted once with the right clocks),
and a change sent while the state sleeps between batches shows in the status within
OBSERVE_INTERVAL plus slack."""

from __future__ import annotations

import asyncio
import socket
import statistics
import time
from collections.abc import Callable
from contextlib import closing

from live import running_station, wait_for

from gcs.mavlink.dialect import Encoder, MAVLinkMessage, mavlink
from gcs.runtime.station import Station
from gcs.runtime.vehicle import OBSERVE_INTERVAL

#: Datagrams sent before waiting for the link to read them: far fewer than a socket buffer holds,
#: so the kernel drops none, and still many per batch of the state.
CHUNK = 50
#: How late a change may show beyond the state's batch interval on a loaded 2-core machine.
SLACK = 0.15
COPTER_LOITER = 5
COPTER_STABILIZE = 0


def heartbeat(custom_mode: int, armed: bool) -> MAVLinkMessage:
    base_mode = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mavlink.MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    return mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_QUADROTOR,
        mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
        base_mode,
        custom_mode,
        mavlink.MAV_STATE_ACTIVE,
        3,
    )


def sys_status(millivolts: int) -> MAVLinkMessage:
    return mavlink.MAVLink_sys_status_message(0, 0, 0, 500, millivolts, -1, -1, 0, 0, 0, 0, 0, 0)


def attitude(boot_ms: int) -> MAVLinkMessage:
    return mavlink.MAVLink_attitude_message(boot_ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def statustext(text: str) -> MAVLinkMessage:
    return mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_INFO, text.encode())


class Vehicle:
    """A vehicle's packets over UDP into the station, sent as fast as the link reads them."""

    def __init__(self, station: Station, port: int) -> None:
        self.station = station
        self.port = port
        self.encoder = Encoder(1, 1)
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sent = 0

    async def send(self, messages: list[MAVLinkMessage]) -> None:
        for start in range(0, len(messages), CHUNK):
            for msg in messages[start : start + CHUNK]:
                self.socket.sendto(self.encoder.encode(msg), ("127.0.0.1", self.port))
                self.sent += 1
            await wait_for(lambda: self.station.link.stats.framing.packets == self.sent, 10, "the link to read", 0.001)

    def close(self) -> None:
        self.socket.close()

    async def connect(self) -> None:
        await wait_for(lambda: self.station.link.is_open, 10, "the UDP socket")
        await self.send([heartbeat(COPTER_STABILIZE, armed=False)])
        await wait_for(lambda: self.station.vehicle.heartbeats == 1, 10, "the first heartbeat in the state")


def burst() -> list[MAVLinkMessage]:
    """1200 messages, interleaved: heartbeats that alternate armed and mode, a battery that
    rises, 60 STATUSTEXTs and a clock that goes back from 150.5 s to 3.5 s halfway (a reboot)."""
    messages: list[MAVLinkMessage] = []
    for i in range(300):
        messages.append(heartbeat(COPTER_LOITER if i % 2 else COPTER_STABILIZE, armed=i % 2 == 1))
        messages.append(sys_status(10_000 + i))
        messages.append(attitude(1000 + 1000 * i if i < 150 else 2000 + 10 * i))
        if i % 5 == 0:
            messages.append(statustext(f"burst {i // 5}"))
        else:
            messages.append(attitude(1000 + 1000 * i + 500 if i < 150 else 2005 + 10 * i))
    return messages


def test_a_burst_reaches_the_state_whole_and_in_order(udp_port: int) -> None:
    async def scenario() -> tuple[Station, int, list[str]]:
        async with running_station(f"udpin:127.0.0.1:{udp_port}", request_streams=False, estimate=False) as station:
            reboots: list[str] = []
            station.vehicle.rebooted.connect(lambda: reboots.append("rebooted"))
            with closing(Vehicle(station, udp_port)) as vehicle:
                await vehicle.connect()
                await vehicle.send(burst())
            await wait_for(lambda: station.vehicle.heartbeats == 301, 10, "the state to catch up")
            await wait_for(lambda: reboots, 10, "the reboot signal")
            return station, vehicle.sent, reboots

    station, sent, reboots = asyncio.run(scenario())
    assert sent == 1201 and station.link.stats.framing.packets == sent  # nothing lost before the state
    state = station.publish().vehicle
    assert state.heartbeats == 301
    assert state.armed and state.custom_mode == COPTER_LOITER and state.mode == "LOITER"  # the last heartbeat's
    assert state.battery_v == 10.299  # the last SYS_STATUS
    assert [m.text for m in state.messages] == [f"burst {k}" for k in range(59, 9, -1)]  # newest 50, newest first
    logged = [e.data["text"] for e in station.events.recent if e.kind == "statustext"]
    assert logged == [f"burst {k}" for k in range(60)]
    assert state.reboots == 1 and reboots == ["rebooted"]
    noted = [e.detail for e in station.link.events if "rebooted" in e.detail]
    assert noted == ["vehicle rebooted (clock 150.5 s -> 3.5 s)"]


def test_a_change_shows_in_the_status_within_the_batch_interval(udp_port: int) -> None:
    """Each change is sent just after the state took the previous one, so while it sleeps
    between batches: the worst case a user sees."""

    async def reflected(check: Callable[[], bool]) -> float:
        start = time.monotonic()
        await wait_for(check, 10, "the change in the status", 0.002)
        return time.monotonic() - start

    async def scenario() -> list[float]:
        async with running_station(f"udpin:127.0.0.1:{udp_port}", request_streams=False, estimate=False) as station:
            delays: list[float] = []
            with closing(Vehicle(station, udp_port)) as vehicle:
                await vehicle.connect()
                for k in range(1, 11):
                    armed = k % 2 == 1
                    await vehicle.send([heartbeat(COPTER_STABILIZE, armed)])
                    delays.append(await reflected(lambda armed=armed: station.publish().vehicle.armed == armed))
            return delays

    delays = asyncio.run(scenario())
    assert len(delays) == 10
    assert statistics.median(delays) <= OBSERVE_INTERVAL + SLACK, delays
