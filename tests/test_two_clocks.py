"""Two vehicles sending as one system id (two simulators left at sysid 1, one UDP port): the
station says so, and counts no reboot for every message of the younger clock (each re-requested
the streams and restarted the plots). A real reboot still counts (tests/test_vehicle_batching.py)."""

from __future__ import annotations

import asyncio
import socket

from live import running_sim, running_station, wait_for

from gcs.commands.status import format_report
from gcs.mavlink.dialect import Encoder, mavlink
from gcs.runtime.boot_clock import BootClock, Step
from gcs.runtime.sequence_watch import STEPS_BACK, WINDOW_S, SequenceWatch


def test_two_simulators_on_one_system_id_are_told_apart_from_a_reboot(udp_port):
    async def scenario():
        address = f"udpout:127.0.0.1:{udp_port}"
        async with (
            running_station(f"udpin:127.0.0.1:{udp_port}", estimate=False) as station,
            running_sim(address, profile="px4"),
        ):
            clock = station.vehicle.clock
            await wait_for(lambda: (clock.last or 0.0) > 3.0, 60, "the first vehicle's clock past 3 s")
            # booted now: its clock starts again; PX4 streams ATTITUDE unasked (the station asked the first)
            async with running_sim(address, profile="px4"):
                await wait_for(lambda: station.publish().vehicle.two_senders, 30, "two clocks told apart")
                await wait_for(lambda: (clock.last or 0.0) > 8.0, 60, "both clocks going on for a while")
                return station.publish().vehicle, [e.detail for e in station.link.events]

    vehicle, events = asyncio.run(scenario())
    assert vehicle.two_senders and vehicle.reboots == 0, vehicle
    # the first step back reads as a reboot until the old clock comes again, then none do (every
    # message of the younger clock was one)
    assert len([e for e in events if "rebooted" in e]) == 1, events
    told = [e for e in events if e.startswith("two vehicles are sending as system 1")]
    assert len(told) == 1 and "MAV_SYSID" in told[0], events


def test_a_reboot_whose_new_clock_passes_the_old_one_is_still_one_reboot():
    """The new clock climbs past where the old one stopped, by itself (no jump): one reboot."""
    clock = BootClock()
    readings = [t / 10 for t in range(30, 60)] + [t / 10 for t in range(0, 100)]
    steps = [clock.step(t, now=k * 0.1) for k, t in enumerate(readings)]
    assert steps.count(Step.REBOOT) == 1 and Step.TWO_CLOCKS not in steps and clock.reboots == 1


def test_a_reboot_then_a_long_silence_is_no_second_clock():
    """After a reboot the link goes quiet for as long as the old clock had run: the new clock comes
    back near the old one's time (a forward jump), 50 s of the host's later: still one reboot."""
    clock = BootClock()
    for t, now in ((50.0, 0.0), (50.1, 0.1), (2.0, 0.2), (2.1, 0.3), (2.2, 0.4), (52.0, 50.2), (52.1, 50.3)):
        clock.step(t, now)
    assert not clock.two_senders and clock.reboots == 1


async def _send_two_vehicles_on_sysid_1(port: int, offset_s: float) -> None:
    """Two vehicles powered up `offset_s` apart, both at sysid 1 compid 1, each with its own
    sequence numbers, sending HEARTBEAT at 1 Hz and ATTITUDE at 50 Hz into one UDP port."""
    senders = [(Encoder(1, 1), 10.0), (Encoder(1, 1), 10.0 + offset_s)]
    senders[1][0].mav.seq = 100  # each counts its own packets, from where it happens to be
    heartbeat = mavlink.MAVLink_heartbeat_message(2, 3, 81, 0, 4, 3)  # an ArduCopter quad
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for k in range(10**6):
            for encoder, start in senders:
                t = start + k * 0.02
                if k % 50 == 0:
                    sock.sendto(encoder.encode(heartbeat), ("127.0.0.1", port))
                attitude = mavlink.MAVLink_attitude_message(int(t * 1000), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
                sock.sendto(encoder.encode(attitude), ("127.0.0.1", port))
            await asyncio.sleep(0.02)  # the stream's pace, not a wait on the station


def test_two_vehicles_powered_up_together_are_told_apart_by_their_sequence_numbers(udp_port):
    """Clocks 0.3 s apart never step back past REBOOT_JUMP, so the clock alone cannot see them
    (the old code said nothing); their packets' sequence numbers interleave."""

    async def scenario():
        async with running_station(f"udpin:127.0.0.1:{udp_port}", estimate=False) as station:
            sending = asyncio.create_task(_send_two_vehicles_on_sysid_1(udp_port, offset_s=0.3))
            try:
                await wait_for(lambda: station.publish().vehicle.two_senders, 30, "two senders told apart")
            finally:
                sending.cancel()
            snapshot = station.publish()
            return snapshot, [e.detail for e in station.link.events]

    snapshot, events = asyncio.run(scenario())
    assert snapshot.vehicle.reboots == 0, snapshot.vehicle
    told = [e for e in events if e.startswith("two vehicles are sending as system 1")]
    assert len(told) == 1 and "sequence numbers interleave" in told[0], events
    # every step between the two senders' numbers counted as packets lost: the loss is unknown
    assert snapshot.link.stats.packets_lost > 0
    assert "lost unknown (two senders" in format_report(snapshot), format_report(snapshot)


def test_one_sender_reordered_now_and_then_is_not_two():
    """A network that reorders a few packets a second, for a minute: below STEPS_BACK per window."""
    watch = SequenceWatch()
    per_second = STEPS_BACK / WINDOW_S / 2
    seen = [watch.check(int(k * per_second / 10), now=k / 10) for k in range(600)]
    assert not any(seen) and not watch.interleaved
    # the same watch then sees a burst of STEPS_BACK within a window
    assert watch.check(int(600 * per_second / 10), 60.1) is False
    assert watch.check(int(600 * per_second / 10) + STEPS_BACK, 61.0) is True
