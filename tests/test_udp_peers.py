"""A `udpin` link answers the senders it heard lately, UDP_MAX_PEERS at most: a datagram from
each of many source ports (anyone who reaches the port can send them) neither grows its peer
table without bound nor makes each of the station's packets go to every one of them. Real
sockets on loopback."""

from __future__ import annotations

import asyncio
import socket

from live import wait_for

from gcs.transport.address import Address
from gcs.transport.pipes import UDP_MAX_PEERS, UdpTransport

SENDERS = 1000


def test_a_flood_of_source_addresses_is_not_each_sent_the_stations_packets(udp_port):
    async def scenario() -> None:
        transport = UdpTransport(Address("udpin", host="127.0.0.1", port=udp_port))
        received: list[bytes] = []
        await transport.open(received.append, None)
        senders = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(SENDERS)]
        vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            vehicle.sendto(b"vehicle", ("127.0.0.1", udp_port))
            await wait_for(lambda: len(received) == 1, 10, "the vehicle's datagram")
            for s in senders:
                s.setblocking(False)
                s.sendto(b"\xfd", ("127.0.0.1", udp_port))
            await wait_for(lambda: len(received) == 1 + SENDERS, 30, "every sender's datagram")
            vehicle.sendto(b"vehicle", ("127.0.0.1", udp_port))  # the vehicle goes on sending
            await wait_for(lambda: len(received) == 2 + SENDERS, 10, "the vehicle's second datagram")
            assert len(transport.peers) == UDP_MAX_PEERS
            transport.write(b"heartbeat")
            vehicle.settimeout(10)
            assert vehicle.recv(64) == b"heartbeat"  # the vehicle, heard last, still gets it
            answered = 0
            for s in senders:
                try:
                    s.recv(64)
                    answered += 1
                except BlockingIOError:
                    pass
            assert answered <= UDP_MAX_PEERS - 1, f"the station's packet went to {answered} of {SENDERS} senders"
        finally:
            transport.close()
            for s in [*senders, vehicle]:
                s.close()

    asyncio.run(scenario())
