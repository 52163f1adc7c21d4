"""A UDP flood's losses are counted where they happen: in the kernel. A real link on a real
loopback socket is flooded while its event loop cannot read; the datagrams the kernel dropped
(SO_RXQ_OVFL) reach the link's counters and equal the kernel's own count in /proc/net/udp,
where the sequence-number loss counter, wrapping at 256, sees only a fraction."""

from __future__ import annotations

import asyncio
import socket
from pathlib import Path

from live import wait_for

from gcs.mavlink.dialect import Encoder, mavlink
from gcs.runtime.link import Link

FLOOD = 20_000  # datagrams: far more than a 4 MiB receive buffer holds (~1 KiB of kernel memory each)


def proc_udp_socket(port: int) -> list[str]:
    """The /proc/net/udp fields of the IPv4 UDP socket bound to 127.0.0.1:port."""
    local = f"0100007F:{port:04X}"
    for line in Path("/proc/net/udp").read_text().splitlines()[1:]:
        fields = line.split()
        if fields[1] == local:
            return fields
    raise AssertionError(f"no UDP socket on 127.0.0.1:{port} in /proc/net/udp")


def proc_udp_drops(port: int) -> int:
    """The kernel's drop count of that socket."""
    return int(proc_udp_socket(port)[-1])


def proc_udp_queued(port: int) -> int:
    """Bytes the kernel holds in that socket's receive queue (tx_queue:rx_queue, in hex)."""
    return int(proc_udp_socket(port)[4].split(":")[1], 16)


def test_flood_kernel_drops_are_counted_and_match_the_kernel(udp_port):
    report = asyncio.run(asyncio.wait_for(flood(udp_port), 120))
    print(f"\nUDP flood: {report}")
    assert report["kernel_drops"] > 0, report
    assert report["kernel_drops"] == report["proc_drops"], report
    assert report["packets"] + report["kernel_drops"] == FLOOD + 1, report
    assert report["sequence_lost"] < report["kernel_drops"], report  # what the issue found


async def flood(udp_port: int) -> dict:
    link = Link(f"udpin:127.0.0.1:{udp_port}")
    task = asyncio.create_task(link.run())
    try:
        await wait_for(lambda: link.is_open, 10, "the UDP socket")
        encoder = Encoder(1, 1)
        heartbeat = mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, mavlink.MAV_STATE_ACTIVE, 3
        )
        packets = [encoder.encode(heartbeat) for _ in range(FLOOD + 1)]
        sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        for packet in packets[:-1]:  # no await: the event loop cannot read meanwhile
            sender.sendto(packet, ("127.0.0.1", udp_port))
        await wait_for(lambda: link.stats.framing.packets > 0, 30, "the flood's first packets")
        # everything the kernel kept has been read (a read hands its datagrams to the link at once)
        await wait_for(lambda: proc_udp_queued(udp_port) == 0, 60, "the socket's receive queue read empty")
        settled = link.stats.framing.packets
        # the drop count travels with each datagram: one more carries the flood's total
        sender.sendto(packets[-1], ("127.0.0.1", udp_port))
        await wait_for(lambda: link.stats.framing.packets == settled + 1, 10, "the last packet")
        sender.close()
        stats = link.snapshot().stats
        return {
            "packets": stats.packets,
            "kernel_drops": stats.kernel_drops,
            "proc_drops": proc_udp_drops(udp_port),
            "sequence_lost": stats.packets_lost,
        }
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
