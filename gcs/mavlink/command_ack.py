"""Which COMMAND_ACK answers a command the station sent: on a shared link (a router, a mesh radio)
the vehicle acks every ground station's commands and its other components ack theirs, and the
first ack of the awaited command id was taken for ours (a gimbal's DENIED refused a stream the
autopilot had accepted).

An ack answers ours when it has our command id, comes from the component the command was sent to
(any of the system's for a broadcast to component 0), and, where it names whom it is for (MAVLink
2's target_system/target_component, which ArduPilot and PX4 fill in), names us. A MAVLink 1 ack
names no one (nor does a MAVLink 2 ack with 0 there): another ground station's ack of the same
command to the same component can still be taken for ours, as can one from a station that uses
our own ids (docs/vehicles.md).
"""

from __future__ import annotations

from gcs.mavlink.dialect import MAVLinkMessage


def answers(
    ack: MAVLinkMessage, sender: tuple[int, int], command: int, to: tuple[int, int], us: tuple[int, int]
) -> bool:
    """Whether COMMAND_ACK `ack` from (sysid, compid) `sender` answers our `command`, sent to
    (sysid, compid) `to` by (sysid, compid) `us`."""
    if ack.command != command or sender[0] != to[0] or to[1] not in (0, sender[1]):
        return False
    for_system = getattr(ack, "target_system", 0)
    if not for_system:
        return True  # names no one: MAVLink 1, or older firmware
    return for_system == us[0] and getattr(ack, "target_component", 0) in (0, us[1])
