"""The real ArduCopter SITL (../shared/sitl) restarted behind a UDP port the station keeps open: the
new boot numbers its packets from 0 again, and the jump from where the old boot's numbers had got
to is no packet lost. Before, only a reopened transport started a new sequence, so this jump
counted as 255 - (the old boot's last number) packets lost whenever that was under 128. The old
boot is stopped while its numbers are between OLD_SEQ (so the jump would count 55-105 lost); the
new boot is seen as a reboot by its clock (gcs.runtime.boot_clock) and the loss stays as it was.
"""

from __future__ import annotations

import asyncio

import pytest
from live import running_station, wait_for
from test_sitl_copter import sitl_process

pytestmark = pytest.mark.slow

#: The old boot is stopped while its sequence numbers are in this range.
OLD_SEQ = range(150, 201)
#: ... after its clock passed this (s): the new boot's first clock reading, once its streams are
#: asked for again, comes well before.
OLD_CLOCK_S = 25.0


@pytest.mark.timeout(240)
def test_a_vehicle_rebooted_behind_an_open_udp_port_adds_no_lost_packets(tmp_path, udp_port):
    serial0 = f"udpclient:127.0.0.1:{udp_port}"

    async def scenario():
        async with running_station(f"udpin:127.0.0.1:{udp_port}", estimate=False) as station:
            # the new boot streams nothing until asked again: asked soon, its clock still short of
            # the old boot's (a clock that went back is how the station knows a reboot)
            station.streams.check_interval, station.streams.retry_interval = 0.5, 1.0
            vehicle, stats = station.vehicle, station.link.stats
            attitude = station.link.bus.subscribe("test", types=("ATTITUDE",), maxlen=10)
            seq = [-1]

            def old_seq_in_range() -> bool:
                for item in attitude.drain():
                    seq[0] = item.raw[4]  # MAVLink 2: the header's sequence number
                return seq[0] in OLD_SEQ

            with sitl_process(tmp_path / "first", "arducopter", "+", "copter.parm", 1, serial0):
                await wait_for(lambda: (vehicle.clock.last or 0.0) > OLD_CLOCK_S, 120, "the first boot's clock")
                await wait_for(old_seq_in_range, 30, f"the first boot's sequence numbers in {OLD_SEQ}", poll=0.002)
            lost_before = stats.packets_lost()
            with sitl_process(tmp_path / "second", "arducopter", "+", "copter.parm", 1, serial0):
                await wait_for(lambda: vehicle.clock.reboots == 1, 90, "the second boot's clock (a reboot)")
                packets = stats.framing.packets
                await wait_for(lambda: stats.framing.packets > packets + 500, 60, "500 packets of the second boot")
                lost_after = stats.packets_lost()
            attitude.close()
            events = [e.detail for e in station.link.events if "rebooted" in e.detail]
            return seq[0], lost_before, lost_after, events

    last_seq, lost_before, lost_after, events = asyncio.run(scenario())
    # the old code counted the jump, 255 - last_seq + the new boot's first number: 55 or more
    assert lost_after - lost_before < 10, (last_seq, lost_before, lost_after, events)
    assert len(events) == 1 and "not counted as lost" in events[0], events
