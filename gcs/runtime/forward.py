"""Forwarding outputs (`--out udpout:127.0.0.1:14551`, repeatable), so Mission Planner,
QGroundControl, MAVProxy or a MAVSDK script can share the station's links.

Every packet from every link (each vehicle of a fleet, gcs.runtime.fleet) is written to each
output unchanged (the original bytes, sequence numbers and signatures intact). What the other
side sends is decoded into whole packets, so its bytes never interleave with the ground
station's own on a serial link, and passed on unchanged as a MAVLink router does: to the link
its target system was last heard on, or to every link when it has no target, targets every
system (0) or one not heard yet.
"""

from __future__ import annotations

import asyncio
from collections.abc import Sequence

from gcs.mavlink.framing import MavlinkDecoder
from gcs.runtime.keep_open import keep_open
from gcs.runtime.link import Link
from gcs.runtime.snapshots import OutputSnapshot
from gcs.transport.address import Address, parse_address
from gcs.transport.pipes import Transport, make_transport


class Output:
    def __init__(self, address: str | Address, links: Sequence[Link]) -> None:
        self.address = parse_address(address) if isinstance(address, str) else address
        self.links = list(links)
        self.decoder = MavlinkDecoder()
        self.packets_out = 0
        self.packets_in = 0
        self._transport: Transport | None = None
        self._datagram = self.address.kind in ("udpin", "udpout")
        self._heard_on: dict[int, Link] = {}  # sysid -> the link it was last heard on
        #: set once its first open has been tried (opened or refused): a replayed .tlog waits for
        #: it, which at --speed 0 was read to its end before the output opened, forwarding nothing
        self.tried = asyncio.Event()

    async def run(self) -> None:
        for link in self.links:
            link.outputs.append(self)
        try:
            await keep_open(
                lambda: make_transport(self.address),
                self._from_peer,
                self.links[0]._event,
                self._set_transport,
                on_refused=lambda _: self.tried.set(),
            )
        finally:
            for link in self.links:
                link.outputs.remove(self)

    def write(self, packet: bytes, link: Link, sysid: int) -> None:
        """A packet `link` received from system `sysid`."""
        self._heard_on[sysid] = link
        if self._transport is not None:
            self._transport.write(packet)
            self.packets_out += 1

    def _from_peer(self, data: bytes) -> None:
        for msg in self.decoder.feed(data, final=self._datagram):
            self.packets_in += 1
            packet = bytes(msg.get_msgbuf())
            system = getattr(msg, "target_system", 0)
            target = self._heard_on.get(system or -1)
            if target is not None:
                target.send_raw(packet, system)
                continue
            for link in self.links:
                link.send_raw(packet)

    def _set_transport(self, transport: Transport | None) -> None:
        self._transport = transport
        if transport is not None:
            self.tried.set()

    def snapshot(self) -> OutputSnapshot:
        return OutputSnapshot(str(self.address), self._transport is not None, self.packets_out, self.packets_in)
