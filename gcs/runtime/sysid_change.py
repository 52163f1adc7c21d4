"""A vehicle's system id changed with no word of it heard: another ground station's write of
MAV_SYSID / SYSID_THISMAV whose echo was lost. ArduPilot sends as the new id at once, on the same
channel, so its stream goes on: its packets' sequence numbers (counted per channel, not per id)
continue from the old id's last, and the old id falls silent from the new one's first packet on.

The rule (docs/vehicles.md): a new system is a vehicle on the same link renamed when its first
packet came from the vehicle's component id while that vehicle was connected (its last heartbeat
within the link's heartbeat timeout), the vehicle sent nothing since, the sequence number goes on
from the vehicle's last (at most SEQUENCE_SLACK packets lost between), and the new id's first
heartbeat names the same autopilot and MAV_TYPE. Its heartbeats are taken for the vehicle's only
once the vehicle has been silent CONFIRM_S while the new id sends (until then the new id is not
served): at its first heartbeat, maybe its first packet, a vehicle still on may just not have
spoken again yet, and two vehicles must never merge. A vehicle switched on as another goes silent
starts its own sequence and is never taken for it; nor is a change at a reboot (PX4's MAV_SYS_ID),
whose new stream starts afresh just as another vehicle's would.
"""

from __future__ import annotations

from dataclasses import dataclass

#: s the old id must have been silent, while the new id sends, before they are taken for one
#: vehicle: a vehicle that is on heartbeats at least once a second.
CONFIRM_S = 1.5
#: The new id's first sequence number may be at most this far past the old id's last: packets lost
#: between them (a second's worth on a lossy radio), and 1 in 16 of an unrelated stream's.
SEQUENCE_SLACK = 16


@dataclass(frozen=True, slots=True)
class FirstPacket:
    """A system's first packet on a link."""

    host_time: float  # monotonic s
    seq: int
    compid: int
    #: sysid → packets every other system had sent on the link by then
    packets_before: dict[int, int]


def continues(
    first: FirstPacket,
    old: int,
    old_packets: int,
    old_last_seq: int | None,
    old_last_heartbeat: float | None,
    heartbeat_timeout: float,
    now: float,
) -> bool | None:
    """Whether the new system whose first packet is `first` goes on with system `old`'s stream, at
    host time `now` (None: it may, but `old` has not been silent CONFIRM_S yet): `old_packets`
    its packets on the link now, `old_last_seq` its last sequence number (None: unknown, the link
    reconnected since), `old_last_heartbeat` when its last heartbeat came."""
    if old_last_seq is None or old_last_heartbeat is None:
        return False
    if first.packets_before.get(old) != old_packets:
        return False  # it spoke after the new system's first packet: two senders
    if first.host_time - old_last_heartbeat > heartbeat_timeout:
        return False  # silent before the new system came: not one stream
    if not 0 < (first.seq - old_last_seq) % 256 <= SEQUENCE_SLACK:
        return False
    return True if now - first.host_time >= CONFIRM_S else None
