"""Forwarding outputs (`--out udpout:127.0.0.1:14551`, repeatable), so Mission Planner,
QGroundControl, MAVProxy or a MAVSDK script can share one radio link.

Every packet from the vehicle is written to each output unchanged (the original bytes,
sequence numbers and signatures intact). What the other side sends is decoded into whole
packets and passed to the vehicle unchanged, so its bytes never interleave with the ground
station's own packets on a serial link.
"""

from __future__ import annotations

from gcs.mavlink.framing import MavlinkDecoder
from gcs.runtime.link import Link, keep_open
from gcs.runtime.snapshots import OutputSnapshot
from gcs.transport.address import Address, parse_address
from gcs.transport.pipes import Transport, make_transport


class Output:
    def __init__(self, address: str | Address, link: Link) -> None:
        self.address = parse_address(address) if isinstance(address, str) else address
        self.link = link
        self.decoder = MavlinkDecoder()
        self.packets_out = 0
        self.packets_in = 0
        self._transport: Transport | None = None
        self._datagram = self.address.kind in ("udpin", "udpout")

    async def run(self) -> None:
        self.link.outputs.append(self)
        try:
            await keep_open(
                lambda: make_transport(self.address), self._from_peer, self.link._event, self._set_transport
            )
        finally:
            self.link.outputs.remove(self)

    def write(self, packet: bytes) -> None:
        if self._transport is not None:
            self._transport.write(packet)
            self.packets_out += 1

    def _from_peer(self, data: bytes) -> None:
        for msg in self.decoder.feed(data, final=self._datagram):
            self.packets_in += 1
            self.link.send_raw(bytes(msg.get_msgbuf()))

    def _set_transport(self, transport: Transport | None) -> None:
        self._transport = transport

    def snapshot(self) -> OutputSnapshot:
        return OutputSnapshot(str(self.address), self._transport is not None, self.packets_out, self.packets_in)
