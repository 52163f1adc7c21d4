"""The link's loss timer (`Link._arm_loss_check`): a vehicle whose heartbeats keep coming stays
connected over many timeouts (the timer armed by its first heartbeat moves on to the last one),
and one that falls silent is declared lost once its last heartbeat is `heartbeat_timeout` old:
not before, and not a timeout later. Real UDP sockets on loopback."""

from __future__ import annotations

import asyncio
import socket

from gcs.mavlink.dialect import Encoder, mavlink
from gcs.runtime.link import Link, LinkEvent, LinkState

TIMEOUT = 2.0
#: between two of the vehicle's heartbeats (its pace, not a wait on the link)
BEAT = 0.2


def test_a_silent_link_is_lost_one_timeout_after_its_last_heartbeat(udp_port):
    beat = Encoder(1, 1).encode(
        mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, mavlink.MAV_STATE_ACTIVE, 3
        )
    )

    async def go() -> tuple[Link, list[LinkState], float]:
        link = Link(f"udpin:127.0.0.1:{udp_port}", heartbeat_timeout=TIMEOUT)
        states: list[LinkState] = []
        lost = asyncio.Event()

        def changed(old: LinkState, new: LinkState) -> None:
            states.append(new)
            if new == LinkState.LOST:
                lost.set()

        link.state_changed.connect(changed)
        run = asyncio.create_task(link.run())
        loop = asyncio.get_running_loop()
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as vehicle:
                async with asyncio.timeout(30):
                    while link.state != LinkState.CONNECTED:  # the link's socket opens
                        vehicle.sendto(beat, ("127.0.0.1", udp_port))
                        await asyncio.sleep(BEAT)
                end = loop.time() + 3 * TIMEOUT
                while loop.time() < end:
                    vehicle.sendto(beat, ("127.0.0.1", udp_port))
                    await asyncio.sleep(BEAT)
            heard = list(states)  # while the heartbeats came
            await asyncio.wait_for(lost.wait(), 3 * TIMEOUT)
        finally:
            run.cancel()
            await asyncio.gather(run, return_exceptions=True)
        assert link.last_heartbeat is not None
        return link, heard, link.last_heartbeat

    link, heard, last = asyncio.run(go())
    assert heard == [LinkState.CONNECTED]
    declared: LinkEvent = next(e for e in link.events if e.detail == "connected -> lost: no heartbeat for 2 s")
    assert TIMEOUT < declared.host_time - last < TIMEOUT + 1.0
