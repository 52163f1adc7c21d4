"""One vehicle's view of a link it may share with other vehicles (a MAVLink router, a mesh radio).

A `VehicleLink` is what a vehicle's core (`Station`) takes for its link: its own bus, state
(waiting → connected → lost, from this vehicle's heartbeats), counters and target (sysid, compid),
while the bytes go through the real `Link` the vehicle was heard on. The fleet
(gcs.runtime.fleet) delivers it the vehicle's messages; what it sends goes out on that link,
addressed to the vehicle and in the MAVLink version the vehicle speaks.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import ClassVar

from gcs.mavlink.dialect import MAVLinkMessage
from gcs.runtime.bus import Message, MessageBus
from gcs.runtime.link import Link, LinkEvent
from gcs.runtime.snapshots import LinkCounters, LinkSnapshot


class VehicleLink(Link):
    """Created unbound (the first vehicle's core exists before anything is heard, as a one-vehicle
    station's does) or bound; `bind` ties it to the link and vehicle it serves."""

    #: the view sending now: the link's `packet_sent` is its alone (others see only the station's
    #: heartbeats and forwarded packets not for one system, `Link.addressed`). Sends are
    #: synchronous, on the loop.
    _sender: ClassVar[VehicleLink | None] = None

    def __init__(self, link: Link) -> None:
        super().__init__(link.address, bus=MessageBus(), heartbeat_timeout=link.heartbeat_timeout, name=link.name)
        self.link: Link | None = None
        self._pace: Callable[[], float] | None = None  # `pace_reads`: asked of the link it is heard on
        #: packets its system lost by sequence number under the ids it had before (`follow_renamed`)
        self._lost_renamed = 0
        self._shown = link
        self._show(link)

    def bind(self, link: Link, sysid: int, compid: int) -> None:
        """Serve vehicle (sysid, compid) heard on `link`."""
        self.link = link
        self.target_system, self.target_component = sysid, compid
        self._show(link)
        if self._pace is not None:
            link.pace_reads(self._pace)

    def pace_reads(self, interval: Callable[[], float]) -> bool:
        """Pace the reads of the link this vehicle is heard on (shared with any other vehicle
        there: the shortest interval asked for holds)."""
        self._pace = interval
        return self._shown.pace_reads(interval)

    @property
    def reads_paced(self) -> bool:
        return self._shown.reads_paced

    def restart_sequence(self, sysid: int, compid: int, since: float) -> int:
        """The link this vehicle is heard on frames its packets and counts their sequence."""
        return self._shown.restart_sequence(sysid, compid, since)

    def _show(self, link: Link) -> None:
        """Report the link's address, framing counters, rejections and signing as this view's,
        and what the station sends on it (its heartbeats reach every vehicle there)."""
        self._shown.packet_sent.disconnect(self._on_link_sent)
        self._shown.noted.disconnect(self._on_link_noted)
        self._shown.transport_closed.disconnect(self._lose_now)
        self._shown = link
        link.packet_sent.connect(self._on_link_sent)
        link.noted.connect(self._on_link_noted)
        link.transport_closed.connect(self._lose_now)
        self.address, self.name, self.baud = link.address, link.name, link.baud
        self.stats.framing = link.stats.framing
        self.stats.nonfinite = link.stats.nonfinite
        self.signing = link.signing
        self._follow_counts()

    def _follow_counts(self) -> None:
        """Its per-type counts (and so its rates) are its system's on the link (`LinkStats.by_system`,
        from its first packet on); before it is bound, the link's. Counted as delivered, they
        held every other system's messages that reach each vehicle (another ground station's, a
        companion's): a GCS's heartbeats doubled the vehicle's HEARTBEAT rate."""
        stats, target = self._shown.stats, self.target_system
        counts = stats.counts if target is None else stats.by_system.setdefault(target, {})
        self.stats.follow(counts, time.monotonic())

    # ---- receive path: the fleet hands over this vehicle's messages ------------------------------
    def deliver(self, item: Message) -> None:
        self.deliver_many([item])

    def deliver_many(self, items: list[Message]) -> None:
        """This vehicle's messages of one wake-up, in order: their bytes counted (per type, the
        link counts them: `_show`), its heartbeats read (what came before one is published first,
        as per message), published in one call."""
        stats, bus, target = self.stats, self.bus, self.target_system
        start = 0
        for i, item in enumerate(items):
            stats.bytes_in += len(item.raw)
            if item.type == "HEARTBEAT" and item.sysid == target:
                if i > start:
                    bus.publish_many(items[start:i])
                    start = i
                self._on_heartbeat(item.msg, item.sysid, item.compid, item.host_time)
        bus.publish_many(items[start:] if start else items)

    # ---- send path: through the link the vehicle was heard on ---------------------------------
    def send(self, msg: MAVLinkMessage, mavlink1: bool | None = None) -> None:
        if self.link is None:
            return  # no vehicle yet: nothing to address
        version = self._encoder.mavlink1 if self.vehicle_mavlink is not None else None
        VehicleLink._sender = self
        try:
            self.link.send(msg, version if mavlink1 is None else mavlink1)
        finally:
            VehicleLink._sender = None

    def send_raw(self, packet: bytes, system: int | None = None) -> None:
        if self.link is None:
            return
        VehicleLink._sender = self
        try:
            self.link.send_raw(packet, system)
        finally:
            VehicleLink._sender = None

    def _on_link_noted(self, event: LinkEvent) -> None:
        """The link's transport events are every vehicle's there (its states are its own)."""
        if event.kind != "state":
            self.noted.emit(event)

    def _on_link_sent(self, packet: bytes) -> None:
        if VehicleLink._sender not in (None, self) or self._shown.addressed not in (None, self.target_system):
            return  # addressed to another vehicle on this link (by its core, or forwarded)
        self.stats.bytes_out += len(packet)
        self.stats.packets_out += 1
        self.packet_sent.emit(packet)

    def _gone(self) -> tuple[float, str] | None:
        return self._shown.transport_gone

    def follow_renamed(self, old: int, new: int) -> None:
        """Its loss under the old id stays its own (its packets do: `Link.follow_renamed`)."""
        self._lost_renamed += sum(n for (sysid, _), n in self.stats.framing.lost.items() if sysid == old)
        super().follow_renamed(old, new)
        self._follow_counts()

    # ---- the rest of Link's surface ---------------------------------------------------------------
    async def run(self) -> None:
        """The state watchdog and rate sampling; the transport is the link's."""
        await self._watchdog_loop()

    @property
    def is_open(self) -> bool:
        return self.link is not None and self.link.is_open

    @property
    def sharing(self) -> int:
        return self.link.sharing if self.link is not None else 1

    def snapshot(self) -> LinkSnapshot:
        own = super().snapshot()
        # the shared link's transport, baud and errors, with this vehicle's own states: the shared
        # link's state follows every vehicle on it, and beside this one's it showed each change twice.
        # Before any vehicle is heard, the link shown (the first): why nothing comes ("cannot open
        # tcp:...: Connection refused; retrying") is what `gcs status` and the page must say then.
        link = self._shown.snapshot()
        shared = [e for e in link.events if e.kind != "state"]
        events = sorted([*shared, *own.events], key=lambda e: e.wall_time)[-50:]
        stats = self._own_loss(dataclasses.replace(own.stats, kernel_drops=link.stats.kernel_drops))
        return dataclasses.replace(
            own,
            transport_open=link.transport_open,
            baud=link.baud,
            stats=stats,
            events=events,
            open_error=link.open_error,
        )

    def _own_loss(self, stats: LinkCounters) -> LinkCounters:
        """`stats` with the packets received from this vehicle's system (its autopilot and its
        other components) and those lost by sequence number from it only. The link's framing
        counts every sender's packets and gaps; shown beside each vehicle on a shared link, the
        sums read as that vehicle's (a copter on a clean route showed the loss of a plane behind a
        lossy radio, and each vehicle the packets of both). Its packets are the link's count for
        its system from the first one on: counted from its first heartbeat, a stream heard from
        the middle left out what came before it, over which the loss was counted. Before a
        vehicle is bound, the link's own figures stand."""
        target = self.target_system
        if target is None:
            return stats
        lost = self._lost_renamed + sum(n for (sysid, _), n in self.stats.framing.lost.items() if sysid == target)
        packets = sum(self.stats.counts.values())  # its system's (`_follow_counts`)
        total = packets + lost
        return dataclasses.replace(
            stats, packets=packets, packets_lost=lost, loss_fraction=round(lost / total, 5) if total else 0.0
        )
