"""The vehicle as its messages describe it: heartbeat (mode, armed), SYS_STATUS (battery, sensor
health), GPS_RAW_INT (fix, satellites, HDOP, the track on a local grid), EKF_STATUS_REPORT or, from
PX4, ESTIMATOR_STATUS (the autopilot estimator's flags), STATUSTEXT (the autopilot's messages, also
recorded in the session's event log); and its clock: reboots, or two vehicles sending as one
system (gcs.runtime.boot_clock)."""

from __future__ import annotations

import asyncio
import math
import time
from collections import deque
from dataclasses import dataclass, field

from pymavlink import mavutil

from gcs.mavlink.dialect import mavlink
from gcs.mavlink.firmware_version import banner_version, version_of
from gcs.mavlink.identity import autopilot_name, enum_name
from gcs.mavlink.statustext import StatusTextJoiner
from gcs.runtime.boot_clock import BootClock, Step
from gcs.runtime.events import EventLog
from gcs.runtime.link import Link
from gcs.runtime.sequence_watch import SequenceWatch
from gcs.runtime.signal import Signal
from gcs.runtime.snapshots import AutopilotMessage, VehicleSnapshot

#: Messages whose time_boot_ms is the vehicle's clock, for reboot detection: the ones the station
#: asks for (gcs.runtime.streams) and ArduPilot and PX4 send by default that carry it.
CLOCK_TYPES = ("ATTITUDE", "SCALED_IMU2", "SCALED_PRESSURE", "GLOBAL_POSITION_INT", "SYSTEM_TIME")
#: What the vehicle state reads (only these are decoded for it).
OBSERVED_TYPES = (
    "HEARTBEAT",
    "SYS_STATUS",
    "GPS_RAW_INT",
    "EKF_STATUS_REPORT",
    "ESTIMATOR_STATUS",
    "STATUSTEXT",
    "AUTOPILOT_VERSION",
    *CLOCK_TYPES,
)

#: The state takes what came in this many seconds at once. The clock it watches for a reboot comes
#: in every turn of a busy link (ATTITUDE), and waking for each, ~100 a second at 1000 msg/s, cost
#: the loop a task step every time; the page reads the state once a second.
OBSERVE_INTERVAL = 0.1
#: STATUSTEXT kept for the page (all of them go to the event log)
MESSAGES_KEPT = 50
#: track points kept (one a second: 15 minutes)
TRACK_KEPT = 900
EARTH_RADIUS_M = 6_371_000.0


def flag_names(enum: str, bits: int, prefix: str) -> list[str]:
    """The names of the bits set in `bits`, without the enum's common prefix."""
    return [e.name.removeprefix(prefix) for v, e in mavlink.enums[enum].items() if v and v & bits and v & (v - 1) == 0]


def flight_mode(autopilot: int, mav_type: int, base_mode: int, custom_mode: int) -> str | None:
    """The mode's name as the firmware calls it (pymavlink's tables: ArduPilot per vehicle type,
    PX4's main and sub mode); the number when the table does not have it."""
    if not base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        return None
    if autopilot == mavlink.MAV_AUTOPILOT_PX4:
        return mavutil.interpret_px4_mode(base_mode, custom_mode)
    table = mavutil.mode_mapping_bynumber(mav_type) if autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA else None
    return (table or {}).get(custom_mode, f"mode {custom_mode}")


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
    clock: BootClock = field(default_factory=BootClock)
    sequence: SequenceWatch = field(default_factory=SequenceWatch)
    heartbeats: int = 0
    mode: str | None = None
    events: EventLog | None = None
    battery_v: float | None = None
    battery_a: float | None = None
    battery_remaining_pct: int | None = None
    sensors_unhealthy: list[str] = field(default_factory=list)
    gps_fix: str | None = None
    gps_satellites: int | None = None
    gps_hdop: float | None = None
    ekf_flags: list[str] = field(default_factory=list)
    ekf_variance_max: float | None = None
    messages: deque[AutopilotMessage] = field(default_factory=lambda: deque(maxlen=MESSAGES_KEPT))
    track: deque[tuple[float, float]] = field(default_factory=lambda: deque(maxlen=TRACK_KEPT))
    _texts: StatusTextJoiner = field(default_factory=StatusTextJoiner)
    _origin: tuple[float, float] | None = None
    _last_track: float = -math.inf
    #: the vehicle's clock went back (a reboot): emitted from the loop, soon after it is seen.
    rebooted: Signal[[]] = field(default_factory=Signal)
    #: other links this system id is heard on, and the MAV_TYPE its heartbeat there names
    #: (`heard_elsewhere`): not served there
    elsewhere: dict[str, str] = field(default_factory=dict)

    async def run(self) -> None:
        sub = self.link.bus.subscribe("vehicle-state", types=OBSERVED_TYPES, maxlen=2000)
        try:
            while True:
                await sub.queue.wait()
                for item in sub.drain():
                    self.observe(item)
                self._watch_sequence(time.monotonic())
                await asyncio.sleep(OBSERVE_INTERVAL)
        finally:
            sub.close()

    def observe(self, item) -> None:
        if item.sysid != self.link.target_system:
            return
        msg = item.msg
        for severity, text in self._texts.expire(item.host_time):
            self._statustext(severity, text)
        if item.type == "HEARTBEAT":
            if item.compid != self.link.target_component:
                return
            self.heartbeats += 1
            self.autopilot = autopilot_name(msg.autopilot)
            self.vehicle_type = enum_name("MAV_TYPE", msg.type)
            self.custom_mode = msg.custom_mode
            self.system_status = enum_name("MAV_STATE", msg.system_status)
            armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            self._flight_state(flight_mode(msg.autopilot, msg.type, msg.base_mode, msg.custom_mode), armed)
        elif item.type == "SYS_STATUS":
            self.battery_v = None if msg.voltage_battery == 0xFFFF else msg.voltage_battery / 1000.0
            self.battery_a = None if msg.current_battery < 0 else msg.current_battery / 100.0
            self.battery_remaining_pct = None if msg.battery_remaining < 0 else msg.battery_remaining
            bad = msg.onboard_control_sensors_present & msg.onboard_control_sensors_enabled
            bad &= ~msg.onboard_control_sensors_health
            self.sensors_unhealthy = flag_names("MAV_SYS_STATUS_SENSOR", bad, "MAV_SYS_STATUS_")
        elif item.type == "GPS_RAW_INT":
            self.gps_fix = enum_name("GPS_FIX_TYPE", msg.fix_type).removeprefix("GPS_FIX_TYPE_").replace("_", " ")
            self.gps_satellites = None if msg.satellites_visible == 255 else msg.satellites_visible
            self.gps_hdop = None if msg.eph == 0xFFFF else msg.eph / 100.0
            if msg.fix_type >= mavlink.GPS_FIX_TYPE_3D_FIX:
                self._track(msg.lat / 1e7, msg.lon / 1e7)
        elif item.type == "EKF_STATUS_REPORT":
            self.ekf_flags = flag_names("EKF_STATUS_FLAGS", msg.flags, "EKF_")
            variances = (msg.velocity_variance, msg.pos_horiz_variance, msg.pos_vert_variance, msg.compass_variance)
            self.ekf_variance_max = max(variances)
        elif item.type == "ESTIMATOR_STATUS":
            # PX4's EKF2 solution flags: the same names as ArduPilot's for bits 1-512, but 1024 is
            # a GPS glitch here (ArduPilot's "uninitialised"); its test ratios are not variances
            self.ekf_flags = flag_names("ESTIMATOR_STATUS_FLAGS", msg.flags, "ESTIMATOR_")
            self.ekf_variance_max = None
        elif item.type == "STATUSTEXT":
            chunk = (getattr(msg, "id", 0), getattr(msg, "chunk_seq", 0))  # MAVLink 1 has neither
            for severity, whole in self._texts.add(msg.severity, msg.text.rstrip("\x00"), *chunk, item.host_time):
                self._statustext(severity, whole)
        elif item.type == "AUTOPILOT_VERSION":
            if self.firmware is None or self.firmware[0].isdigit():  # a banner seen names more
                self.firmware = version_of(msg)
            self.capabilities = msg.capabilities
        if item.vehicle_time is not None and getattr(msg, "time_boot_ms", None) is not None:
            self._clock(item.vehicle_time, item.host_time, item.sysid, item.compid)

    def _flight_state(self, mode: str | None, armed: bool) -> None:
        """Take the heartbeat's mode and arming state; each change is an event (the first
        heartbeat's mode too, and arming found on), so the session says when the vehicle armed
        and which mode it flew in: what the errors of a take-off or a turn are read against."""
        if mode != self.mode and self.events is not None:
            self.events.record("vehicle", "vehicle", event="mode", old=self.mode, new=mode)
        if armed != self.armed and self.events is not None:
            self.events.record("vehicle", "vehicle", event="armed" if armed else "disarmed", mode=mode)
        self.mode, self.armed = mode, armed

    def _clock(self, t: float, now: float, sysid: int, compid: int) -> None:
        step = self.clock.step(t, now)
        if step is Step.REBOOT:
            text = f"vehicle rebooted (clock {self.clock.previous:.1f} s -> {t:.1f} s)"
            # its sequence numbers started again too: the jump is no loss (a reopened port's is
            # not counted at all, but a UDP port stays open across the reboot)
            assert self.clock.previous_at is not None  # a step back has a reading before it
            if taken := self.link.restart_sequence(sysid, compid, self.clock.previous_at):
                text += f"; {taken} packets of its sequence jump not counted as lost"
            self.link._event("state", text)
            asyncio.get_running_loop().call_soon(self.rebooted.emit)
        elif step is Step.TWO_CLOCKS:
            self._two_senders(sysid, f"clocks {t:.1f} s and {self.clock.previous:.1f} s")

    def _watch_sequence(self, now: float) -> None:
        sysid, compid = self.link.target_system, self.link.target_component
        if sysid is None or compid is None or self.clock.two_senders:
            return
        stepped_back = self.link.stats.framing.stepped_back.get((sysid, compid), 0)
        if self.sequence.check(stepped_back, now):
            self.clock.two_senders = True
            self._two_senders(sysid, "their packets' sequence numbers interleave")

    def _two_senders(self, sysid: int, seen: str) -> None:
        text = (
            f"two vehicles are sending as system {sysid} ({seen}): their data mix; give each its own "
            "system id (MAV_SYSID or SYSID_THISMAV), or hear a vehicle through one route only"
        )
        self.link._event("state", text)
        if self.events is not None:
            self.events.record("vehicle", "vehicle", event="two senders", text=text)

    def heard_elsewhere(self, link: str, mav_type: int) -> None:
        """This system id's heartbeat on another link (the fleet serves a system id on the first
        link it is heard on only): the same vehicle through a second route, or, when it names
        another MAV_TYPE, a second vehicle left at the same id, which is shown nowhere else."""
        self.elsewhere[link] = enum_name("MAV_TYPE", mav_type)

    def others(self) -> list[str]:
        """The links where another vehicle (a heartbeat of another MAV_TYPE) sends as this system:
        "tcp:127.0.0.1:5770 (MAV_TYPE_QUADROTOR)"."""
        if self.vehicle_type is None:
            return []
        return [f"{link} ({kind})" for link, kind in self.elsewhere.items() if kind != self.vehicle_type]

    def _track(self, lat: float, lon: float) -> None:
        """Metres north and east of the first 3D fix (equirectangular: exact to well under a
        metre over the few kilometres of a test field), at most one point a second."""
        now = time.monotonic()
        if now - self._last_track < 1.0:
            return
        self._last_track = now
        if self._origin is None:
            self._origin = (lat, lon)
        lat0, lon0 = self._origin
        north = math.radians(lat - lat0) * EARTH_RADIUS_M
        east = math.radians(lon - lon0) * EARTH_RADIUS_M * math.cos(math.radians(lat0))
        self.track.append((round(north, 2), round(east, 2)))

    def _statustext(self, severity: int, text: str) -> None:
        """One whole text (its chunks joined): the page's list, the event log, the firmware banner."""
        text = text.strip()
        if banner := banner_version(text):
            self.firmware = banner
        name = enum_name("MAV_SEVERITY", severity).removeprefix("MAV_SEVERITY_")
        self.messages.appendleft(AutopilotMessage(time.time(), severity, name, text))
        if self.events is not None:
            self.events.record("statustext", "vehicle", severity=severity, severity_name=name, text=text)

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
            reboots=self.clock.reboots,
            two_senders=self.clock.two_senders,
            others=self.others(),
            heartbeats=self.heartbeats,
            mode=self.mode,
            battery_v=self.battery_v,
            battery_a=self.battery_a,
            battery_remaining_pct=self.battery_remaining_pct,
            sensors_unhealthy=list(self.sensors_unhealthy),
            gps_fix=self.gps_fix,
            gps_satellites=self.gps_satellites,
            gps_hdop=self.gps_hdop,
            ekf_flags=list(self.ekf_flags),
            ekf_variance_max=self.ekf_variance_max,
            messages=list(self.messages),
            track_ne_m=list(self.track),
        )
