"""The fleet: every vehicle one ground station hears, on one link or several.

It owns the links (one per `--connect`) and the forwarding outputs, tells vehicles from other
components by their HEARTBEAT (gcs.mavlink.identity), and routes every message by (link, sysid)
to that vehicle's core, a `Station` on a `VehicleLink`. The first core exists from the start,
unbound, as a one-vehicle station's does (the dashboard, the recorder and `gcs status` have it
before anything is heard) and takes the first vehicle heard; each further vehicle gets a new core
at its first heartbeat. Messages from a system that is no vehicle (a GCS, a companion with its own
sysid, a radio's RADIO_STATUS) go to every vehicle on the link they came on, as they did on a
one-vehicle link, except sensor data (some vehicle's not yet heard, never another's); until the
first vehicle is heard, its core gets everything (a link of attitude lines has no heartbeat). The
first core is then bound to the vehicle whose sensor data it already took, if any (its estimation
and recording follow the first system that sent IMU data): a vehicle heard before that one gets a
core of its own, so no session starts with another vehicle's data. A sysid already served on one
link and heard on another stays on the first.

A vehicle whose system id is written (ArduPilot's MAV_SYSID / SYSID_THISMAV, by this station or
another ground station) answers as the new id at once, and its echo, a PARAM_VALUE of that
parameter equal to its sender's id, is the first thing heard from it: its core follows it under
the new id (`_renamed`) rather than a second core starting beside the first, which was left
"lost" for ever. With that echo lost, the new id's stream going on from the vehicle's (its
sequence numbers, the vehicle silent since) tells it (gcs.runtime.sysid_change). Should the old id
send a vehicle heartbeat before the new id's first, the change was not the vehicle's (another
system on the link said so): the core goes back to it (`_back`).
"""

from __future__ import annotations

import asyncio
import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

from gcs.mavlink.identity import ARDUPILOT_SYSID_PARAMS, is_vehicle_heartbeat
from gcs.mavlink.params import param_name
from gcs.mavlink.sampling import IMU_TYPES, INPUT_TYPES
from gcs.runtime.bus import Message, MessageBus
from gcs.runtime.forward import Output
from gcs.runtime.link import Link
from gcs.runtime.signal import Signal
from gcs.runtime.station import Station, StationConfig, signing_of
from gcs.runtime.supervisor import Supervisor
from gcs.runtime.sysid_change import continues
from gcs.runtime.vehicle_link import VehicleLink


@dataclass(frozen=True, slots=True)
class VehicleEntry:
    """One vehicle as the fleet lists it."""

    sysid: int | None  # None: the first core, before any vehicle is heard
    compid: int | None
    link: str  # the address it is heard on
    station: Station


class _LinkBus(MessageBus):
    """A link's bus: its own subscribers, then each served vehicle's view or the fleet's routing
    (synchronous, never waits)."""

    def __init__(self, fleet: Fleet, index: int) -> None:
        super().__init__()
        self.fleet, self.index = fleet, index
        #: sysid → the view of each vehicle served on this link (set by the fleet when it adopts one)
        self.views: dict[int, VehicleLink] = {}

    def publish_many(self, items: list[Message]) -> None:
        """Each run of messages from a vehicle served here goes to its view in one call; a message
        from any other system goes through the fleet's routing, after what came before it (it
        may adopt a vehicle: the messages after it are looked up again)."""
        if self._all or self._by_type:  # the link's own subscribers (none unless a tool adds one)
            super().publish_many(items)
        views = self.views
        run: list[Message] = []
        to: VehicleLink | None = None
        for item in items:
            view = views.get(item.sysid)
            if view is not to or view is None:
                if run:
                    assert to is not None  # a run is always some view's
                    to.deliver_many(run)
                    run = []
                to = view
                if view is None:  # not served here: routed, in order
                    self.fleet.route(self.index, item)
                    continue
            run.append(item)
        if run:
            assert to is not None
            to.deliver_many(run)

    def wants(self, msg_type: str) -> bool:
        return super().wants(msg_type) or self.fleet.wants(self.index, msg_type)


class Fleet:
    """`single`: serve one vehicle only (the commands that address one: params, logs, signing,
    protocol) — `sysid`, or the first heard without it; every other vehicle is ignored."""

    def __init__(
        self, config: StationConfig, connects: Sequence[str] = (), *, single: bool = False, sysid: int | None = None
    ) -> None:
        self.config = config
        self.single, self.sysid = single or sysid is not None, sysid
        addresses = list(connects) or [config.connect]
        #: each link's bus, which also keeps the views of the vehicles served on it (`_LinkBus.views`)
        self._buses = [_LinkBus(self, i) for i in range(len(addresses))]
        self.links = [
            Link(
                address,
                bus=self._buses[i],
                baud=config.baud,
                speed=config.speed,
                heartbeat_timeout=config.heartbeat_timeout,
                ascii_format=config.ascii_format,
                signing=signing_of(config),
                name="vehicle" if i == 0 else f"link {i + 1}",
            )
            for i, address in enumerate(addresses)
        ]
        #: `--out` forwards every link (every packet, whichever vehicle sent it; gcs.runtime.forward)
        self.outputs = [Output(address, self.links) for address in config.outputs]
        first = Station(config, link=VehicleLink(self.links[0]), outputs=self.outputs)
        self.supervisor = Supervisor(first.events)
        self._entries: list[VehicleEntry] = [VehicleEntry(None, None, str(self.links[0].address), first)]
        self._unbound: Station | None = first
        #: the system whose IMU data the waiting first core took first: the one its estimation (and
        #: a replay of its session) follows, so the one it is bound to (None: no IMU data yet)
        self._unbound_system: int | None = None
        self._on_link: list[list[VehicleLink]] = [[] for _ in self.links]  # bound views per link
        self._ignored: set[tuple[int, int]] = set()  # (link, sysid): served on another link, or not followed
        #: (link, sysid) → the system id its core follows since, and when it moved (host monotonic
        #: s; `_renamed`, undone by `_back`)
        self._left: dict[tuple[int, int], tuple[int, float]] = {}
        self._started = False
        #: the sysid of every vehicle heard, followed or not (what a `--sysid` never heard is told)
        self.heard: set[int] = set()
        #: a vehicle heard for the first time (its core just started), on the event loop
        self.vehicle_added: Signal[[VehicleEntry]] = Signal()

    # ---- lifecycle ------------------------------------------------------------------------------
    @property
    def first(self) -> Station:
        """The first vehicle's core (the one the one-vehicle URLs and commands use)."""
        return self._entries[0].station

    async def start(self) -> None:
        self._started = True
        self.first.launch()
        for i, output in enumerate(self.outputs):  # first: a replayed .tlog's link waits for them
            self.supervisor.start(f"output {i + 1}", output.run())
        for i, link in enumerate(self.links):
            self.supervisor.start("link" if i == 0 else f"link {i + 1}", link.run())

    async def stop(self) -> None:
        """The links first (nothing arrives while the cores finish), then every core."""
        await self.supervisor.stop()
        await asyncio.gather(*(entry.station.stop() for entry in self._entries))

    # ---- vehicles -------------------------------------------------------------------------------
    def vehicles(self) -> list[VehicleEntry]:
        """Every vehicle in the order heard (the first core even before it is bound)."""
        return list(self._entries)

    def vehicle(self, sysid: int) -> Station | None:
        return next((e.station for e in self._entries if e.sysid == sysid), None)

    # ---- routing --------------------------------------------------------------------------------
    def wants(self, index: int, msg_type: str) -> bool:
        """Whether a core that link `index` may deliver to reads this type (the link decodes it)."""
        if self._unbound is not None and _view(self._unbound).bus.wants(msg_type):
            return True
        return any(view.bus.wants(msg_type) for view in self._on_link[index])

    def route(self, index: int, item: Message) -> None:
        """A message from a system not served on this link (`_LinkBus.publish` delivers the others)."""
        key = (index, item.sysid)
        if key in self._ignored:
            return  # a vehicle served on another link, or one a single-vehicle fleet does not follow
        if item.type == "HEARTBEAT" and is_vehicle_heartbeat(item.msg):
            self._adopt(index, item)
            return
        if item.type == "PARAM_VALUE" and (renamed := self._renamed(index, item)) is not None:
            renamed.deliver(item)  # its parameter client takes the new value as its vehicle's
            return
        if item.type not in INPUT_TYPES:  # a GCS, a companion, a radio: as on a one-vehicle link
            for view in self._on_link[index]:  # (sensor data is some vehicle's: never another's)
                view.deliver(item)
        if self._unbound is not None:
            if item.type in INPUT_TYPES and self.single and self.sysid not in (None, item.sysid):
                return  # sensor data of another vehicle than the one `--sysid` names
            if self._unbound_system is None and item.type in IMU_TYPES:
                self._unbound_system = item.sysid
            _view(self._unbound).deliver(item)

    def _adopt(self, index: int, item: Message) -> None:
        """A vehicle's first heartbeat on this link: bind the waiting first core, or start a new one."""
        link = self.links[index]
        self.heard.add(item.sysid)
        if (moved := self._back(index, item) or self._renamed(index, item)) is not None:
            moved.deliver(item)
            return
        if self._may_be_renamed(index, item):
            return  # a vehicle here renamed, maybe: a later heartbeat tells (gcs.runtime.sysid_change)
        takes_first = self._unbound is not None and self._unbound_system in (None, item.sysid)
        if self.single and (not takes_first or self.sysid not in (None, item.sysid)):
            self._ignored.add((index, item.sysid))
            return
        served = self.vehicle(item.sysid)
        if served is not None:
            self._ignored.add((index, item.sysid))
            served.events.record("vehicle", "fleet", event="also heard", sysid=item.sysid, link=str(link.address))
            served.vehicle.heard_elsewhere(str(link.address), item.msg.type)
            return
        if takes_first:
            assert self._unbound is not None  # (takes_first)
            core, self._unbound = self._unbound, None
            _view(core).bind(link, item.sysid, item.compid)
            core.follow_system(item.sysid)
            self._entries[0] = VehicleEntry(item.sysid, item.compid, str(link.address), core)
            entry = self._entries[0]
        else:
            view = VehicleLink(link)
            view.bind(link, item.sysid, item.compid)
            core = Station(dataclasses.replace(self.config, outputs=[]), link=view, outputs=[])
            core.follow_system(item.sysid)
            entry = VehicleEntry(item.sysid, item.compid, str(link.address), core)
            self._entries.append(entry)
            if self._started:
                core.launch()
        self._buses[index].views[item.sysid] = _view(core)
        self._on_link[index].append(_view(core))
        MessageBus.epoch += 1  # who reads what on each link changed (Link decodes by `wants`)
        address = str(link.address)
        core.events.record("vehicle", "fleet", event="heard", sysid=item.sysid, compid=item.compid, link=address)
        self.vehicle_added.emit(entry)
        _view(core).deliver(item)  # its parts subscribe when their tasks first run: they see the next one

    def _renamed(self, index: int, item: Message) -> VehicleLink | None:
        """A vehicle served on this link that now sends as `item`'s system, its core moved to serve
        it under that id (its view returned; None when none is). Told by a PARAM_VALUE from a
        system not served here saying its own system id is its sender's (the echo of the write:
        the vehicle whose core is writing it, else the only one there with that component id), or
        by a new system's first heartbeat while a core on this link writes that id (its echo lost),
        or whose stream goes on from a vehicle's here (`_continued`: another station's write, its
        echo lost)."""
        msg, new = item.msg, item.sysid
        if msg is None or self.vehicle(new) is not None:
            return None
        echo = item.type == "PARAM_VALUE"
        if echo and (param_name(msg) not in ARDUPILOT_SYSID_PARAMS or msg.param_value != new):
            return None
        here = [(i, e) for i, e in enumerate(self._entries) if _view(e.station) in self._on_link[index]]
        same = [(i, e) for i, e in here if e.compid == item.compid and e.sysid != new]
        writing = [(i, e) for i, e in same if e.station.params.renaming_to == new]
        chosen = (
            (writing or same) if echo else (writing or [(i, e) for i, e in same if self._continued(index, e, item)])
        )
        if len(chosen) != 1:
            return None  # none, or two vehicles with that component id here, neither writing it
        i, entry = chosen[0]
        assert entry.sysid is not None  # (a bound core's entry)
        self._left[(index, entry.sysid)] = (new, item.host_time)
        return self._move(index, i, new, "system id changed")

    def _back(self, index: int, item: Message) -> VehicleLink | None:
        """The core that left `item`'s system id for another, moved back to it (its view; None
        when no core left that id): the vehicle still sends heartbeats as itself, so the change
        was not its own. Another system saying "my SYSID_THISMAV is my id" looks like the echo of
        a write by another ground station: one such PARAM_VALUE moved the first vehicle's page,
        recording and writes to that system, and the vehicle itself became a second vehicle. Only
        until the new id's first vehicle heartbeat: after that the rename was real, and a vehicle
        heard as the old id is another airframe (one switched on with the default id 1, which is
        why the first was renamed)."""
        left = self._left.pop((index, item.sysid), None)
        if left is None:
            return None
        moved, at = left
        here = [(i, e) for i, e in enumerate(self._entries) if _view(e.station) in self._on_link[index]]
        found = [i for i, e in here if e.sysid == moved]
        if len(found) != 1 or self.vehicle(item.sysid) is not None:
            return None
        beat = _view(self._entries[found[0]].station).last_heartbeat
        if beat is not None and beat >= at:
            return None
        return self._move(index, found[0], item.sysid, "system id change undone")

    def _move(self, index: int, i: int, new: int, event: str) -> VehicleLink:
        """Entry `i`'s core, on link `index`, follows system `new` from now on."""
        entry = self._entries[i]
        old, view, link = entry.sysid, _view(entry.station), self.links[index]
        assert old is not None  # (a bound core's entry)
        bus = self._buses[index]
        del bus.views[old]
        bus.views[new] = view
        link.follow_renamed(old, new)
        view.follow_renamed(old, new)
        entry.station.follow_system(new)
        self._entries[i] = dataclasses.replace(entry, sysid=new)
        self.heard.add(new)
        MessageBus.epoch += 1
        address = str(link.address)
        entry.station.events.record("vehicle", "fleet", event=event, old=old, new=new, link=address)
        return view

    def _may_be_renamed(self, index: int, item: Message) -> bool:
        """The new system of heartbeat `item` may go on with a vehicle's stream on link `index`, not
        yet known (`_continued` undecided for some vehicle)."""
        here = [e for e in self._entries if _view(e.station) in self._on_link[index]]
        return any(self._continued(index, e, item) is None for e in here if e.compid == item.compid)

    def _continued(self, index: int, entry: VehicleEntry, item: Message) -> bool | None:
        """Whether the new system of heartbeat `item` goes on with `entry`'s vehicle's stream on link
        `index` (its id changed by another station, the echo lost: gcs.runtime.sysid_change);
        None: not known yet."""
        link, view, old = self.links[index], _view(entry.station), entry.sysid
        first = link.first_packets.get(item.sysid)
        if old is None or first is None or first.compid != entry.compid:
            return False
        if view.vehicle_kind != (item.msg.autopilot, item.msg.type):
            return False
        packets = sum(link.stats.by_system.get(old, {}).values())
        last_seq = link.last_sequence(old, first.compid)
        return continues(first, old, packets, last_seq, view.last_heartbeat, link.heartbeat_timeout, item.host_time)


def _view(core: Station) -> VehicleLink:
    link = core.link
    assert isinstance(link, VehicleLink)  # every core of a fleet runs on a vehicle's view
    return link
