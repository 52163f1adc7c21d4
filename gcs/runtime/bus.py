"""The message bus: every packet received, stamped, fanned out to subscribers.

The link publishes from its receive callback and must never wait, so each subscriber has
its own bounded queue; when a slow subscriber's queue is full the OLDEST message is dropped
and counted for that subscriber alone. Publishing costs one append per interested subscriber;
the link publishes what one wake-up brought in one call (`publish_many`).
"""

from __future__ import annotations

from collections.abc import Iterable

from gcs.mavlink.decoding import decode
from gcs.mavlink.dialect import MAVLinkMessage
from gcs.mavlink.imu_packets import ImuPacket
from gcs.mavlink.sampling import INPUT_TYPES
from gcs.runtime.dropqueue import DropOldestQueue

#: Vehicle time fields above this many µs are UNIX-epoch times (e.g. GPS_RAW_INT.time_usec on
#: ArduPilot), not time since boot.
_EPOCH_US = 10**15


class Message:
    """A MAVLink packet as it arrived: its bytes, type and source always; the decoded pymavlink
    message (`msg`) built on first use. The link builds it at once for the types some subscriber
    asked for by name (it checks their values, gcs.mavlink.finite), except the IMU types, which it
    reads from the bytes (`imu`, what the estimation takes) and which are decoded only for a part
    that reads `msg`; a subscriber to every type (the recorder) takes the bytes, so a type no part
    reads is never decoded.

    host_time: the host's monotonic clock at arrival, s (for latency and rates).
    wall_time: the host's UNIX time at arrival, s (for .tlog records).
    vehicle_time: the sender's time since boot in s, from time_usec or time_boot_ms when the
    message has one (None otherwise: AHRS2, SIMSTATE, HEARTBEAT, ...); it decodes the message.
    """

    __slots__ = ("raw", "type", "host_time", "wall_time", "sysid", "compid", "link", "_msg", "imu")

    def __init__(
        self,
        raw: bytes,
        type: str,
        host_time: float,
        wall_time: float,
        sysid: int,
        compid: int,
        link: str = "",
        msg: MAVLinkMessage | None = None,
        imu: ImuPacket | None = None,
    ) -> None:
        self.raw = raw
        self.type = type
        self.host_time = host_time
        self.wall_time = wall_time
        self.sysid = sysid
        self.compid = compid
        self.link = link
        self._msg = msg
        #: an IMU message's fields read from its bytes by the link (gcs.mavlink.imu_packets)
        self.imu = imu

    @classmethod
    def of(cls, msg: MAVLinkMessage, host_time: float, wall_time: float, link: str = "") -> Message:
        """A message already decoded (or built and packed: its wire bytes are the raw bytes)."""
        header = msg.get_header()
        raw = bytes(msg.get_msgbuf())
        return cls(raw, msg.get_type(), host_time, wall_time, header.srcSystem, header.srcComponent, link, msg)

    @property
    def msg(self) -> MAVLinkMessage:
        if self._msg is None:
            self._msg = decode(self.raw)
        return self._msg

    @property
    def reading(self) -> MAVLinkMessage | ImuPacket:
        """What the estimation reads (`MessageInputs.feed`): the IMU packet the link read from the
        bytes, else the decoded message."""
        return self.imu if self.imu is not None else self.msg

    @property
    def decoded(self) -> bool:
        """Whether the pymavlink message has been built (by the link, or by a reader of `msg`)."""
        return self._msg is not None

    @property
    def vehicle_time(self) -> float | None:
        return vehicle_time_of(self.msg)


def vehicle_time_of(msg: MAVLinkMessage) -> float | None:
    """Time since boot in seconds from the message's own time field, if it has one."""
    usec = getattr(msg, "time_usec", None)
    if usec is not None:
        return usec / 1e6 if 0 < usec < _EPOCH_US else None
    ms = getattr(msg, "time_boot_ms", None)
    if ms is not None:
        return ms / 1e3
    return None


class Subscription:
    """One subscriber's bounded queue (`DropOldestQueue`). Iterate it with `async for`, or call
    `get()`, `next()` or `drain()`."""

    def __init__(self, bus: MessageBus, name: str, types: frozenset[str] | None, maxlen: int) -> None:
        self.bus = bus
        self.name = name
        self.types = types
        self.queue: DropOldestQueue[Message] = DropOldestQueue(maxlen)
        self.delivered = 0

    @property
    def dropped(self) -> int:
        return self.queue.dropped

    async def get(self, timeout: float | None = None) -> Message | None:
        """The oldest queued message, waiting for one; None if `timeout` s pass first."""
        return self.queue.get_nowait() if await self.queue.wait(timeout) else None

    async def next(self) -> Message:
        """The oldest queued message, waiting as long as it takes."""
        await self.queue.wait()
        return self.queue.get_nowait()

    def drain(self, limit: int | None = None) -> list[Message]:
        """Everything queued now (at most `limit` messages), without waiting."""
        return self.queue.drain(limit)

    def __aiter__(self) -> Subscription:
        return self

    async def __anext__(self) -> Message:
        return await self.next()

    def close(self) -> None:
        self.bus.unsubscribe(self)


class MessageBus:
    #: changes with every subscription made or closed on any bus: what a link caches about who
    #: reads which type (`wants`) is stale once it moves (rare: parts subscribe as they start).
    epoch = 0

    def __init__(self) -> None:
        self._all: list[Subscription] = []
        self._by_type: dict[str, list[Subscription]] = {}
        self.published = 0
        self.inputs_published = 0  # messages of the estimation's input types (a recording's input positions)

    def subscribe(self, name: str, types: Iterable[str] | None = None, maxlen: int = 10_000) -> Subscription:
        """A new subscriber for the given message types (None: every message)."""
        sub = Subscription(self, name, frozenset(types) if types is not None else None, maxlen)
        MessageBus.epoch += 1
        if sub.types is None:
            self._all.append(sub)
        else:
            for t in sub.types:
                self._by_type.setdefault(t, []).append(sub)
        return sub

    def unsubscribe(self, sub: Subscription) -> None:
        MessageBus.epoch += 1
        if sub.types is None:
            if sub in self._all:
                self._all.remove(sub)
        else:
            for t in sub.types:
                subs = self._by_type.get(t, [])
                if sub in subs:
                    subs.remove(sub)
                if not subs:
                    self._by_type.pop(t, None)

    def wants(self, msg_type: str) -> bool:
        """Whether a subscriber asked for this type by name (so reads its fields: decode it)."""
        return msg_type in self._by_type

    def publish(self, item: Message) -> None:
        self.publish_many([item])

    def publish_many(self, items: list[Message]) -> None:
        """`publish` of each item in turn: every subscriber's queue gets the same items in the same
        order (a subscriber to every type takes them in one call)."""
        self.published += len(items)
        by_type, inputs = self._by_type, 0
        for item in items:
            if item.type in INPUT_TYPES:
                inputs += 1
            for sub in by_type.get(item.type, ()):
                sub.queue.put(item)
                sub.delivered += 1
        self.inputs_published += inputs
        for sub in self._all:
            sub.queue.put_many(items)
            sub.delivered += len(items)

    def subscriptions(self) -> list[Subscription]:
        seen: dict[int, Subscription] = {id(s): s for s in self._all}
        for subs in self._by_type.values():
            seen.update((id(s), s) for s in subs)
        return list(seen.values())
