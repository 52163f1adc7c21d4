"""The link to one vehicle: a transport kept open, MAVLink decoded, counted and published,
the ground station's own heartbeat sent, and the link state followed.

State: waiting → connected (first autopilot heartbeat) → lost (no heartbeat for
`heartbeat_timeout` s, or at once when the transport closes by itself) → connected again,
automatically. A lost link says why (`lost_reason`):
the transport's own end when it closed since the last heartbeat (a serial port gone with its
errno's words, the TCP peer's close, a socket error), else the silence. A serial port that vanishes is
reopened when it comes back, a TCP peer that drops is redialled with backoff, UDP resumes
when packets return: never a restart.
"""

from __future__ import annotations

import asyncio
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum

from gcs.mavlink.ascii import SEED000, AsciiAttitudeDecoder, AsciiFormat
from gcs.mavlink.decoding import decode
from gcs.mavlink.dialect import MARKER_V2, Encoder, MAVLinkMessage, mavlink
from gcs.mavlink.finite import nonfinite_axis, nonfinite_field
from gcs.mavlink.framing import Frame, MavlinkDecoder
from gcs.mavlink.identity import is_vehicle_heartbeat
from gcs.mavlink.imu_packets import IMU_PACKET_TYPES, imu_packet
from gcs.mavlink.signing import Signing
from gcs.runtime.baud import AUTO_BAUDS, detect_baud
from gcs.runtime.bus import Message, MessageBus
from gcs.runtime.keep_open import keep_open
from gcs.runtime.link_stats import LinkStats
from gcs.runtime.signal import Signal
from gcs.runtime.snapshots import LinkNote, LinkSnapshot
from gcs.runtime.sysid_change import FirstPacket
from gcs.transport.address import Address, parse_address
from gcs.transport.pipes import Transport, make_transport

#: how the receive path reads a type some part reads (`Link._decoded`; 0: it is not read)
_DECODE, _READ_IMU = 1, 2

GCS_SYSID = 255
#: s a replayed .tlog waits for its forwarding outputs' first open (a TCP peer may not answer)
OUTPUTS_WAIT = 5.0
GCS_COMPID = mavlink.MAV_COMP_ID_MISSIONPLANNER  # 190, as ground stations use


class LinkState(StrEnum):
    WAITING = "waiting"
    CONNECTED = "connected"
    LOST = "lost"


@dataclass(frozen=True, slots=True)
class LinkEvent:
    """Something that happened to the link, for the status page and the session log."""

    host_time: float
    wall_time: float
    kind: str  # "state", "transport", "baud", "error", "rejected"
    detail: str


class Link:
    """One vehicle link. Create it, then `await link.run()` (until cancelled or replay ends)."""

    def __init__(
        self,
        address: str | Address,
        *,
        bus: MessageBus | None = None,
        baud: int | str = 57600,
        speed: float = 1.0,
        heartbeat_timeout: float = 3.0,
        heartbeat_rate: float = 1.0,
        name: str = "vehicle",
        ascii_format: AsciiFormat = SEED000,
        signing: Signing | None = None,
    ) -> None:
        self.address = parse_address(address) if isinstance(address, str) else address
        self.bus = bus or MessageBus()
        self.baud = baud
        self.speed = speed
        self.heartbeat_timeout = heartbeat_timeout
        self.heartbeat_rate = heartbeat_rate
        self.name = name
        self.state = LinkState.WAITING
        self.events: deque[LinkEvent] = deque(maxlen=1000)
        self.stats = LinkStats()
        self.ascii_format = ascii_format
        self.decoder = self._new_decoder()
        self.stats.framing = self.decoder.counters
        self.outputs: list = []  # gcs.runtime.forward.Output
        self.target_system: int | None = None
        self.target_component: int | None = None
        self.vehicle_mavlink: int | None = None  # 1 or 2: what the vehicle speaks
        self.last_heartbeat: float | None = None  # host monotonic s
        #: why the link is lost, while it is ("no heartbeat for 3 s", "/dev/ttyUSB0 closed: ...")
        self.lost_reason: str | None = None
        #: while its transport cannot be opened: why ("cannot open tcp:HOST:PORT: Connection refused")
        self.open_error: str | None = None
        #: the last transport that closed by itself: (host monotonic s, "ADDRESS closed: why")
        self.transport_gone: tuple[float, str] | None = None
        self.vehicles_heard: dict[int, int] = {}  # sysid -> MAVLink version of each vehicle heard here
        #: sysid → its first packet here: a new id going on with a vehicle's stream (gcs.runtime.sysid_change)
        self.first_packets: dict[int, FirstPacket] = {}
        #: (autopilot, MAV_TYPE) of the followed vehicle's last heartbeat
        self.vehicle_kind: tuple[int, int] | None = None
        self.addressed: int | None = None  # while packet_sent runs: the one system it is for, if any
        self._encoder = Encoder(GCS_SYSID, GCS_COMPID, mavlink1=True)
        #: MAVLink 2 signing (gcs.mavlink.signing): what we send is signed, what arrives checked
        self.signing = signing
        if signing is not None:
            signing.sign_with(self._encoder)
        self._transport: Transport | None = None
        self._read_intervals: list[Callable[[], float]] = []  # `pace_reads`: for every transport opened
        self._closed_drops = 0  # kernel drops of transports closed since
        self._datagram = self.address.kind in ("udpin", "udpout", "tlog")
        #: (old, new) on every state change, in the event loop.
        self.state_changed: Signal[[LinkState, LinkState]] = Signal()
        #: every event as it is added to `events`, in the event loop
        self.noted: Signal[[LinkEvent]] = Signal()
        #: its transport closed by itself (`transport_gone` says why), in the event loop
        self.transport_closed: Signal[[]] = Signal()
        #: every packet sent to the vehicle (ours and forwarded ones), so a recording holds both directions.
        self.packet_sent: Signal[[bytes]] = Signal()
        self._connected = asyncio.Event()
        #: while the watchdog runs: its loop, and the timer that declares the link lost (`_arm_loss_check`)
        self._watch_loop: asyncio.AbstractEventLoop | None = None
        self._loss_check: asyncio.TimerHandle | None = None
        #: message type → read on arrival (a part reads it): 0, _DECODE or _READ_IMU, as of MessageBus.epoch `_epoch`
        self._decoded: dict[str, int] = {}
        self._epoch = -1

    # ---- public API -------------------------------------------------------------------
    async def run(self) -> None:
        tasks = [asyncio.create_task(self._heartbeat_loop()), asyncio.create_task(self._watchdog_loop())]
        try:
            if self.address.kind == "serial" and self.baud == "auto":
                await self._detect_baud()
            if self.address.kind == "tlog":
                await self._outputs_tried()
            await keep_open(
                self._make_transport,
                self._on_data,
                self._event,
                self._set_transport,
                on_batch=self._on_datagrams,
                on_refused=self._refused,
            )
        finally:
            for t in tasks:
                t.cancel()

    async def wait_connected(self, timeout: float | None = None) -> bool:
        try:
            async with asyncio.timeout(timeout):
                await self._connected.wait()
            return True
        except TimeoutError:
            return False

    @property
    def is_open(self) -> bool:
        return self._transport is not None

    def pace_reads(self, interval: Callable[[], float]) -> bool:
        """Read the vehicle's datagrams at most once per interval() s (gcs.transport.pipes): True
        on a UDP link, the only transport whose wake-ups the station can space out. Every vehicle
        of a fleet heard here asks for its own (its dashboard's frame interval): the shortest
        holds, so that none gets its messages later than it asked."""
        if self.address.kind not in ("udpin", "udpout"):
            return False
        if interval not in self._read_intervals:
            self._read_intervals.append(interval)
        if self._transport is not None:
            self._transport.pace_reads(self._read_interval)
        return True

    @property
    def reads_paced(self) -> bool:
        """The vehicle's datagrams come at most once per interval: a reader of this link's
        messages gets them in batches already."""
        return bool(self._read_intervals)

    def _read_interval(self) -> float:
        """The shortest interval asked for (`pace_reads`), s."""
        return min(interval() for interval in self._read_intervals)

    def send(self, msg: MAVLinkMessage, mavlink1: bool | None = None) -> None:
        """Send a message from the ground station, in the protocol version the vehicle speaks
        (`mavlink1`: the version of one vehicle among several on this link, gcs.runtime.fleet)."""
        encoder = self._encoder
        if mavlink1 is None or mavlink1 == encoder.mavlink1:
            self.send_raw(encoder.encode(msg))
            return
        encoder.mavlink1 = mavlink1
        try:
            packet = encoder.encode(msg)
        finally:
            encoder.mavlink1 = not mavlink1
        self.send_raw(packet)

    def send_raw(self, packet: bytes, system: int | None = None) -> None:
        """`system`: the one system the packet is for (a forwarded one, gcs.runtime.forward), so
        only that vehicle's view of a shared link counts and records it (gcs.runtime.vehicle_link).
        Nothing goes to a text device (it reads no MAVLink) nor to a replayed .tlog (a file is no
        vehicle: what was sent to it counted as sent, and showed in `gcs status`)."""
        if self._transport is None or self.address.framing == "ascii" or self.address.kind == "tlog":
            return
        self._transport.write(packet)
        self.stats.bytes_out += len(packet)
        self.stats.packets_out += 1
        self.addressed = system
        try:
            self.packet_sent.emit(packet)
        finally:
            self.addressed = None

    async def _outputs_tried(self) -> None:
        """Until each forwarding output has tried to open (at most OUTPUTS_WAIT s): a replayed file
        loses nothing by waiting, and at --speed 0 it was read to its end first, forwarding nothing."""
        waits = [asyncio.ensure_future(output.tried.wait()) for output in self.outputs]
        if waits:
            _, pending = await asyncio.wait(waits, timeout=OUTPUTS_WAIT)
            for wait in pending:
                wait.cancel()

    def follow_renamed(self, old: int, new: int) -> None:
        """Vehicle `old` took the system id `new` (its MAV_SYSID written, gcs.runtime.fleet): follow
        it as that system, its heartbeats going on as its own."""
        if old in self.vehicles_heard:
            self.vehicles_heard[new] = self.vehicles_heard.pop(old)
        by_system = self.stats.by_system
        if old in by_system:  # its packets under both ids are one vehicle's
            counts = by_system.pop(old)
            for msg_type, n in by_system.pop(new, {}).items():
                counts[msg_type] = counts.get(msg_type, 0) + n
            by_system[new] = counts
        if self.target_system == old:
            self.target_system = new
            self._event("state", f"the vehicle is system {new} now (was {old})")

    def restart_sequence(self, sysid: int, compid: int, since: float) -> int:
        """A sender rebooted: its sequence numbers started again (`MavlinkDecoder.restart_sequence`).
        Returns the packets no longer counted as lost."""
        decoder = self.decoder
        return decoder.restart_sequence((sysid, compid), since) if isinstance(decoder, MavlinkDecoder) else 0

    def snapshot(self) -> LinkSnapshot:
        now = time.monotonic()
        self.stats.kernel_drops = self._closed_drops + (self._transport.kernel_drops if self._transport else 0)
        return LinkSnapshot(
            name=self.name,
            address=str(self.address),
            state=str(self.state),
            transport_open=self.is_open,
            baud=self.baud if self.address.kind == "serial" else None,
            target_system=self.target_system,
            target_component=self.target_component,
            mavlink_version=self.vehicle_mavlink,
            heartbeat_age_s=None if self.last_heartbeat is None else round(now - self.last_heartbeat, 3),
            lost_reason=self.lost_reason if self.state == LinkState.LOST else None,
            open_error=self.open_error,
            stats=self.stats.snapshot(),
            events=[LinkNote(e.wall_time, e.kind, e.detail) for e in list(self.events)[-50:]],
            signing=None if self.signing is None else self.signing.snapshot(),
        )

    # ---- receive path -----------------------------------------------------------------
    def _on_data(self, data: bytes) -> None:
        """A chunk of a byte stream (or one datagram): its packets, as `_receive`."""
        now, wall = time.monotonic(), time.time()
        self.stats.bytes_in += len(data)
        self._receive(self.decoder.frames(data, final=self._datagram), now, wall)

    def _on_datagrams(self, datagrams: list[bytes]) -> None:
        """The datagrams one wake-up of a UDP socket read, as `_receive`, stamped once: the time
        the station read them, as a stream's chunk is stamped."""
        now, wall = time.monotonic(), time.time()
        stats, decoder = self.stats, self.decoder
        for data in datagrams:
            stats.bytes_in += len(data)
        if isinstance(decoder, MavlinkDecoder):
            frames = decoder.datagram_frames(datagrams)
        else:  # seed 000-style text in datagrams
            frames = [frame for data in datagrams for frame in decoder.frames(data, final=True)]
        self._receive(frames, now, wall)

    def _read_modes(self) -> dict[str, int]:
        """Message type → how the receive path reads it, as of the bus's subscriptions now."""
        if self._epoch != MessageBus.epoch:  # someone subscribed or left: ask the bus again
            self._epoch = MessageBus.epoch
            self._decoded.clear()
        return self._decoded

    def _receive(self, frames: list[Frame], now: float, wall: float) -> None:
        """Every intact packet is counted, forwarded and published as bytes; only the types a
        subscriber asked for by name (and HEARTBEAT, which the link reads) are decoded here (the
        IMU types only read from their bytes, gcs.mavlink.imu_packets), and those are checked for
        non-finite values (gcs.mavlink.finite) before anything sees them.

        The messages go to the bus in one call (`MessageBus.publish_many`) up to each HEARTBEAT,
        which the link reads before publishing it as it did per message: what a state change
        sets off (a request sent, the recorder's drain before it records the send) sees every
        message before the heartbeat published, and who reads which type is asked again after."""
        counts, by_system = self.stats.counts, self.stats.by_system
        signing, outputs, bus, name = self.signing, self.outputs, self.bus, self.name
        decoded = self._read_modes()
        pending: list[Message] = []
        for raw, msg_type, sysid, compid in frames:
            if signing is not None and (why := signing.check(raw, msg_type)) is not None:
                self._refuse_unsigned(msg_type, why)
                continue
            counts[msg_type] = counts.get(msg_type, 0) + 1
            own = by_system.get(sysid)
            if own is None:
                own = self._first_packet(raw, sysid, compid, now)
            own[msg_type] = own.get(msg_type, 0) + 1
            msg = imu = None
            read = decoded.get(msg_type)
            if read is None:
                wanted = msg_type == "HEARTBEAT" or bus.wants(msg_type)
                read = decoded[msg_type] = (_READ_IMU if msg_type in IMU_PACKET_TYPES else _DECODE) if wanted else 0
            if read:
                if read == _READ_IMU:
                    imu = imu_packet(raw, msg_type, sysid)
                    field = nonfinite_axis(imu)
                else:
                    msg = decode(raw)
                    field = nonfinite_field(msg, msg_type)
                if field is not None:
                    self._reject(msg_type, field)
                    continue
            for out in outputs:
                out.write(raw, self, sysid)
            item = Message(raw, msg_type, now, wall, sysid, compid, name, msg, imu)
            if msg_type == "HEARTBEAT":
                if pending:
                    bus.publish_many(pending)
                    pending = []
                self._on_heartbeat(msg, sysid, compid, now)
                bus.publish_many([item])
                decoded = self._read_modes()
                continue
            pending.append(item)
        if pending:
            bus.publish_many(pending)

    def _first_packet(self, raw: bytes, sysid: int, compid: int, now: float) -> dict[str, int]:
        """A system's first packet here: remembered (`first_packets`); its counts, new."""
        by_system = self.stats.by_system
        seq = raw[4] if raw[0] == MARKER_V2 else raw[2]
        before = {s: sum(counts.values()) for s, counts in by_system.items()}
        self.first_packets[sysid] = FirstPacket(now, seq, compid, before)
        own: dict[str, int] = {}
        by_system[sysid] = own
        return own

    def last_sequence(self, sysid: int, compid: int) -> int | None:
        """The last sequence number of (sysid, compid) since the transport opened (None: none,
        or text lines)."""
        decoder = self.decoder
        return decoder.last_sequence((sysid, compid)) if isinstance(decoder, MavlinkDecoder) else None

    def _reject(self, msg_type: str, field: str) -> None:
        """A message with a non-finite value where the station needs a number goes nowhere;
        the first of each type is also a link event, so the status page says what arrived."""
        first = msg_type not in self.stats.nonfinite
        self.stats.nonfinite[msg_type] = self.stats.nonfinite.get(msg_type, 0) + 1
        if first:
            self._event("rejected", f"{msg_type} with non-finite {field} (counted, not used)")

    def _refuse_unsigned(self, msg_type: str, why: str) -> None:
        """A packet signing refuses goes nowhere (counted in signing); the first of each reason
        is also a link event."""
        assert self.signing is not None
        if self.signing.counters.rejected.get(why) == 1:
            self._event("rejected", f"{msg_type}: {why} (signing required; counted, not used)")

    def _on_heartbeat(self, msg, sysid: int, compid: int, now: float) -> None:
        if not is_vehicle_heartbeat(msg):
            return  # another ground station, a gimbal, a companion: not the vehicle
        version = 2 if msg.get_msgbuf()[0] == MARKER_V2 else 1
        self.vehicles_heard[sysid] = version
        if self.target_system is None:
            self.target_system, self.target_component = sysid, compid
        elif (sysid, compid) != (self.target_system, self.target_component):
            return
        self.vehicle_kind = (msg.autopilot, msg.type)
        if version != self.vehicle_mavlink:
            self.vehicle_mavlink = version
            self._encoder.mavlink1 = version == 1 and self.signing is None
        self.last_heartbeat = now
        if self.state != LinkState.CONNECTED:
            self._set_state(LinkState.CONNECTED)
        self._arm_loss_check()

    # ---- periodic work ----------------------------------------------------------------
    async def _heartbeat_loop(self) -> None:
        msg = mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE, 3
        )
        period = 1.0 / self.heartbeat_rate
        while True:
            for mavlink1 in self._heartbeat_versions():
                self.send(msg, mavlink1)
            await asyncio.sleep(period)

    @property
    def sharing(self) -> int:
        """How many vehicles share this link's air time (a radio's budget is split between them)."""
        return max(1, len(self.vehicles_heard))

    def _heartbeat_versions(self) -> tuple[bool | None, ...]:
        """The station's heartbeat goes out in every MAVLink version the vehicles on this link
        speak: an APM 2.5 drops MAVLink 2 frames (it would never hear the station), and a MAVLink 2
        vehicle should not be offered MAVLink 1 alone. A signed link speaks MAVLink 2 only."""
        if self.signing is None and len(set(self.vehicles_heard.values())) > 1:
            return (True, False)
        return (None,)  # the version of the vehicle this link follows

    async def _watchdog_loop(self) -> None:
        """The rates sampled once a second, and the link declared lost `heartbeat_timeout` s after
        its last heartbeat by a timer the heartbeats move on (`_arm_loss_check`), instead of a look
        ten times a second (docs/benchmarks.md, "`gcs serve` when little arrives")."""
        self._watch_loop = asyncio.get_running_loop()
        self._arm_loss_check()  # a heartbeat may have come before the watchdog started (a fleet's core)
        try:
            while True:
                self.stats.sample(time.monotonic())
                await asyncio.sleep(1.0)
        finally:
            self._watch_loop = None
            if self._loss_check is not None:
                self._loss_check.cancel()
                self._loss_check = None

    def _arm_loss_check(self) -> None:
        """While the watchdog runs and the link is connected: wake up when the last heartbeat is
        `heartbeat_timeout` old (each heartbeat moves the timer on: no wake-up while they come)."""
        if self._loss_check is not None:
            self._loss_check.cancel()
            self._loss_check = None
        if self._watch_loop is None or self.state != LinkState.CONNECTED or self.last_heartbeat is None:
            return
        due = self.last_heartbeat + self.heartbeat_timeout - time.monotonic()
        # 1 ms past the deadline: the loop's timers are as coarse, and the link is lost only once
        # its heartbeat is strictly older than the timeout
        self._loss_check = self._watch_loop.call_later(max(due, 0.0) + 0.001, self._check_lost)

    def _check_lost(self) -> None:
        self._loss_check = None
        if (
            self.state == LinkState.CONNECTED
            and self.last_heartbeat is not None
            and time.monotonic() - self.last_heartbeat > self.heartbeat_timeout
        ):
            self.lost_reason = self._loss_reason(self.last_heartbeat)
            self._set_state(LinkState.LOST)
        else:
            self._arm_loss_check()

    def _lose_now(self) -> None:
        """The transport closed by itself: nothing can arrive until it reopens, so a connected link
        is lost now, with the transport's reason, not a heartbeat timeout later."""
        if self.state == LinkState.CONNECTED and self.last_heartbeat is not None:
            if self._loss_check is not None:
                self._loss_check.cancel()
                self._loss_check = None
            self.lost_reason = self._loss_reason(self.last_heartbeat)
            self._set_state(LinkState.LOST)

    def _loss_reason(self, last_heartbeat: float) -> str:
        """Why a link whose last heartbeat came at `last_heartbeat` is lost: its transport's end
        when one closed by itself since (what the field engineer must fix: the cable, the
        port, the peer), else the silence (a radio fade, a vehicle switched off)."""
        gone = self._gone()
        if gone is not None and gone[0] >= last_heartbeat:
            return gone[1]
        return f"no heartbeat for {self.heartbeat_timeout:g} s"

    def closed_since(self, since: float) -> str | None:
        """Why the transport is closed, when it closed by itself at or after `since` (host monotonic
        s) and is not open again (a serial port gone); None otherwise. Nothing can come through it:
        a request waiting for an answer stops and names this."""
        gone = self._gone()
        if not self.is_open and gone is not None and gone[0] >= since:
            return gone[1]
        return None

    def down_reason(self, since: float) -> str | None:
        """Why no answer came: the transport closed since `since` (`closed_since`), or the link is
        lost (its `lost_reason`); None while it is up. A request that got no answer names this,
        not its own timeout alone."""
        closed = self.closed_since(since)
        if closed is not None:
            return closed
        return self.lost_reason if self.state == LinkState.LOST else None

    def _gone(self) -> tuple[float, str] | None:
        """The last transport of the link this vehicle is heard on that closed by itself."""
        return self.transport_gone

    # ---- helpers ----------------------------------------------------------------------
    def _new_decoder(self) -> MavlinkDecoder | AsciiAttitudeDecoder:
        """MAVLink framing, or seed 000-style text lines (an ascii: address) turned into MAVLink."""
        return AsciiAttitudeDecoder(self.ascii_format) if self.address.framing == "ascii" else MavlinkDecoder()

    def _make_transport(self) -> Transport:
        baud = self.baud if isinstance(self.baud, int) else AUTO_BAUDS[0]
        return make_transport(self.address, baud=baud, speed=self.speed)

    def _peer_gone(self, why: str) -> None:
        """The other end went while the transport stays open (a `tcpin` client hung up): lost now,
        as when a transport closes by itself."""
        self.transport_gone = (time.monotonic(), f"{self.address}: {why}")
        self.transport_closed.emit()
        self._lose_now()

    def _refused(self, why: str | None) -> None:
        self.open_error = why

    def _set_transport(self, transport: Transport | None) -> None:
        old = self._transport
        if old is not None:  # closed: its drops stay counted
            self._closed_drops += old.kernel_drops
            if transport is None and old.close_reason is not None:
                self.transport_gone = (time.monotonic(), f"{old.address} closed: {old.close_reason}")
                self.transport_closed.emit()
                self._lose_now()
        self._transport = transport
        if transport is not None:
            transport.on_peer_gone = self._peer_gone
            self.decoder.new_stream()
            if self._read_intervals:
                transport.pace_reads(self._read_interval)

    def _set_state(self, new: LinkState) -> None:
        old, self.state = self.state, new
        if new == LinkState.CONNECTED:
            self._connected.set()
            self.lost_reason = None
        else:
            self._connected.clear()
        why = f": {self.lost_reason}" if new == LinkState.LOST and self.lost_reason else ""
        self._event("state", f"{old} -> {new}{why}")
        self.state_changed.emit(old, new)

    def _event(self, kind: str, detail: str) -> None:
        event = LinkEvent(time.monotonic(), time.time(), kind, detail)
        self.events.append(event)
        self.noted.emit(event)

    async def _detect_baud(self) -> None:
        """Keep the first of the usual baud rates that yields a valid packet (gcs.runtime.baud)."""
        self.baud = await detect_baud(self.address, self._new_decoder, self._event)
        self._event("baud", f"detected {self.baud} baud on {self.address}")
