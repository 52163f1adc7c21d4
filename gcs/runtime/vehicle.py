"""The vehicle as its heartbeats describe it, and reboot detection from its clock."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field

from gcs.mavlink.dialect import mavlink
from gcs.runtime.firmware import banner_version, version_of
from gcs.runtime.link import Link
from gcs.runtime.signal import Signal
from gcs.runtime.snapshots import VehicleSnapshot

#: The vehicle clock going back by more than this (s) is a reboot, not jitter or reordering.
REBOOT_JUMP = 1.0

_AUTOPILOTS = {
    mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA: "ArduPilot",
    mavlink.MAV_AUTOPILOT_PX4: "PX4",
    mavlink.MAV_AUTOPILOT_GENERIC: "generic",
}


def enum_name(enum: str, value: int) -> str:
    entry = mavlink.enums.get(enum, {}).get(value)
    return entry.name if entry is not None else str(value)


@dataclass
class VehicleState:
    """Follows HEARTBEAT, AUTOPILOT_VERSION and the clock of timestamped messages."""

    link: Link
    autopilot: str | None = None
    vehicle_type: str | None = None
    armed: bool = False
    custom_mode: int | None = None
    system_status: str | None = None
    firmware: str | None = None
    capabilities: int | None = None
    reboots: int = 0
    heartbeats: int = 0
    _last_boot_time: float | None = None
    #: the vehicle's clock went back (a reboot): emitted from the loop, soon after it is seen.
    rebooted: Signal[[]] = field(default_factory=Signal)

    async def run(self) -> None:
        sub = self.link.bus.subscribe("vehicle-state", maxlen=2000)
        try:
            async for item in sub:
                self.observe(item)
        finally:
            sub.close()

    def observe(self, item) -> None:
        if item.sysid != self.link.target_system:
            return
        msg = item.msg
        if item.type == "HEARTBEAT":
            if item.compid != self.link.target_component:
                return
            self.heartbeats += 1
            self.autopilot = _AUTOPILOTS.get(msg.autopilot, enum_name("MAV_AUTOPILOT", msg.autopilot))
            self.vehicle_type = enum_name("MAV_TYPE", msg.type)
            self.armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            self.custom_mode = msg.custom_mode
            self.system_status = enum_name("MAV_STATE", msg.system_status)
        elif item.type == "AUTOPILOT_VERSION":
            if self.firmware is None or self.firmware[0].isdigit():  # a banner seen names more
                self.firmware = version_of(msg)
            self.capabilities = msg.capabilities
        elif item.type == "STATUSTEXT" and (banner := banner_version(msg.text)):
            self.firmware = banner
        if item.vehicle_time is not None and getattr(msg, "time_boot_ms", None) is not None:
            last = self._last_boot_time
            if last is not None and item.vehicle_time < last - REBOOT_JUMP:
                self.reboots += 1
                self.link._event("state", f"vehicle rebooted (clock {last:.1f} s -> {item.vehicle_time:.1f} s)")
                asyncio.get_running_loop().call_soon(self.rebooted.emit)
            self._last_boot_time = item.vehicle_time

    def snapshot(self) -> VehicleSnapshot:
        return VehicleSnapshot(
            sysid=self.link.target_system,
            compid=self.link.target_component,
            autopilot=self.autopilot,
            vehicle_type=self.vehicle_type,
            mavlink_version=self.link.vehicle_mavlink,
            armed=self.armed,
            custom_mode=self.custom_mode,
            system_status=self.system_status,
            firmware=self.firmware,
            reboots=self.reboots,
            heartbeats=self.heartbeats,
        )
