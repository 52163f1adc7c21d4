"""Two vehicles sending as one system id (two simulators left at sysid 1, one UDP port): the
station says so, and counts no reboot for every message of the younger clock (each re-requested
the streams and restarted the plots). A real reboot still counts (tests/test_vehicle_batching.py)."""

from __future__ import annotations

import asyncio

from live import running_sim, running_station, wait_for

from gcs.runtime.boot_clock import BootClock, Step


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
                await wait_for(lambda: station.publish().vehicle.two_clocks, 30, "two clocks told apart")
                await wait_for(lambda: (clock.last or 0.0) > 8.0, 60, "both clocks going on for a while")
                return station.publish().vehicle, [e.detail for e in station.link.events]

    vehicle, events = asyncio.run(scenario())
    assert vehicle.two_clocks and vehicle.reboots == 0, vehicle
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
    assert clock.two_clocks is None and clock.reboots == 1
