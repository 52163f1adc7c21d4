"""Ask the vehicle for what the estimators need, and check what actually arrives.

Two mechanisms exist in the field:
- MAV_CMD_SET_MESSAGE_INTERVAL, per message, ACKed (ArduPilot 4.x, PX4);
- REQUEST_DATA_STREAM, per group of messages, never ACKed (APM 2.5 / ArduPilot 3.x, where
  ArduCopter sends nothing until asked).
On connect we try the first; a COMMAND_ACK other than ACCEPTED, or silence, selects the
second. Requests are repeated only after a reconnect, a reboot, or when a message stays far
below its requested rate (another ground station may have overridden it), and then at most
once per `retry_interval`: never a flood of requests over a slow radio.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from gcs.mavlink.dialect import mavlink
from gcs.runtime.link import Link, LinkState
from gcs.runtime.snapshots import StreamRate, StreamsSnapshot

#: REQUEST_DATA_STREAM group of each message, as ArduPilot assigns them.
STREAM_GROUPS = {
    "RAW_IMU": mavlink.MAV_DATA_STREAM_RAW_SENSORS,
    "SCALED_IMU2": mavlink.MAV_DATA_STREAM_RAW_SENSORS,
    "SCALED_PRESSURE": mavlink.MAV_DATA_STREAM_RAW_SENSORS,
    "GPS_RAW_INT": mavlink.MAV_DATA_STREAM_EXTENDED_STATUS,
    "ATTITUDE": mavlink.MAV_DATA_STREAM_EXTRA1,
    "AHRS2": mavlink.MAV_DATA_STREAM_EXTRA1,
    "SIMSTATE": mavlink.MAV_DATA_STREAM_EXTRA1,
    "AHRS": mavlink.MAV_DATA_STREAM_EXTRA3,
}

#: Message ids by name, for SET_MESSAGE_INTERVAL.
MESSAGE_IDS = {
    name: getattr(mavlink, f"MAVLINK_MSG_ID_{name}")
    for name in (
        "RAW_IMU",
        "SCALED_IMU2",
        "HIGHRES_IMU",
        "ATTITUDE",
        "ATTITUDE_QUATERNION",
        "AHRS2",
        "SIMSTATE",
        "GPS_RAW_INT",
        "SCALED_PRESSURE",
        "AHRS",
    )
}


@dataclass
class StreamPlan:
    """Rates in Hz wanted for the estimators and the comparison."""

    imu_hz: float = 50.0
    attitude_hz: float = 50.0
    gps_hz: float = 5.0
    aux_hz: float = 5.0  # barometer and onboard-AHRS health

    def for_autopilot(self, autopilot: str | None) -> dict[str, float]:
        if autopilot == "PX4":
            return {"HIGHRES_IMU": self.imu_hz, "ATTITUDE": self.attitude_hz, "GPS_RAW_INT": self.gps_hz}
        return {
            "RAW_IMU": self.imu_hz,
            "SCALED_IMU2": self.imu_hz,
            "ATTITUDE": self.attitude_hz,
            "AHRS2": self.attitude_hz,
            "SIMSTATE": self.attitude_hz,
            "GPS_RAW_INT": self.gps_hz,
            "SCALED_PRESSURE": self.aux_hz,
            "AHRS": self.aux_hz,
        }


@dataclass
class StreamRequester:
    link: Link
    plan: StreamPlan = field(default_factory=StreamPlan)
    ack_timeout: float = 1.0
    retry_interval: float = 10.0
    check_interval: float = 5.0
    method: str | None = None  # "SET_MESSAGE_INTERVAL" | "REQUEST_DATA_STREAM"
    requested: dict[str, float] = field(default_factory=dict)
    acks: dict[str, str] = field(default_factory=dict)
    requests_sent: int = 0
    autopilot: str | None = None
    #: the radio's budget (gcs.runtime.radio.RadioGovernor.cap): wanted rates → rates to request
    rate_cap: Callable[[dict[str, float]], dict[str, float]] | None = None
    _wake: asyncio.Event = field(default_factory=asyncio.Event)
    _last_request: dict[str, float] = field(default_factory=dict)

    def _on_link_state(self, old: LinkState, new: LinkState) -> None:
        if new == LinkState.CONNECTED:
            self.request_again()

    def request_again(self) -> None:
        """Re-request everything soon (after a reconnect or a reboot)."""
        self._wake.set()

    async def run(self) -> None:
        self.link.state_changed.connect(self._on_link_state)
        acks = self.link.bus.subscribe("stream-acks", types=["COMMAND_ACK", "HEARTBEAT"], maxlen=200)
        try:
            while True:
                await self.link.wait_connected()
                self._wake.clear()
                await self._request_all(acks)
                await self._monitor_until_woken()
        finally:
            acks.close()

    async def _request_all(self, acks) -> None:
        self.autopilot = await self._autopilot(acks)
        wanted = self.plan.for_autopilot(self.autopilot)
        if self.rate_cap is not None:
            wanted = self.rate_cap(wanted)
        if self.method != "REQUEST_DATA_STREAM":
            first = next(iter(wanted))
            result = await self._set_interval(first, wanted[first], acks)
            if result == "ACCEPTED":
                self.method = "SET_MESSAGE_INTERVAL"
                for name, hz in list(wanted.items())[1:]:
                    await self._set_interval(name, hz, acks)
            elif self.autopilot != "PX4":
                self.method = "REQUEST_DATA_STREAM"
        if self.method == "REQUEST_DATA_STREAM":
            self._request_streams(wanted)
        self.requested = wanted

    async def _autopilot(self, acks) -> str | None:
        """The autopilot family from the vehicle's heartbeat (waits briefly for one)."""
        deadline = time.monotonic() + 2.0
        for item in acks.drain():
            if item.type == "HEARTBEAT" and item.sysid == self.link.target_system:
                return _family(item.msg.autopilot)
        while (item := await acks.get(timeout=max(deadline - time.monotonic(), 0.0))) is not None:
            if item.type == "HEARTBEAT" and item.sysid == self.link.target_system:
                return _family(item.msg.autopilot)
        return None

    async def _set_interval(self, name: str, hz: float, acks, attempts: int = 2) -> str:
        interval_us = int(round(1e6 / hz)) if hz > 0 else -1
        command = mavlink.MAV_CMD_SET_MESSAGE_INTERVAL
        for _ in range(attempts):
            acks.drain()
            self.link.send(
                mavlink.MAVLink_command_long_message(
                    self.link.target_system or 1,
                    self.link.target_component or 1,
                    command,
                    0,
                    MESSAGE_IDS[name],
                    interval_us,
                    0,
                    0,
                    0,
                    0,
                    0,
                )
            )
            self.requests_sent += 1
            self._last_request[name] = time.monotonic()
            deadline = time.monotonic() + self.ack_timeout
            while (item := await acks.get(timeout=max(deadline - time.monotonic(), 0.0))) is not None:
                if item.type == "COMMAND_ACK" and item.msg.command == command:
                    result = enum_result(item.msg.result)
                    self.acks[name] = result
                    return result
        self.acks[name] = "NO_ACK"
        return "NO_ACK"

    def _request_streams(self, wanted: dict[str, float]) -> None:
        groups: dict[int, float] = {}
        for name, hz in wanted.items():
            group = STREAM_GROUPS.get(name)
            if group is not None:
                groups[group] = max(groups.get(group, 0.0), hz)
        for group, hz in groups.items():
            self.link.send(
                mavlink.MAVLink_request_data_stream_message(
                    self.link.target_system or 1, self.link.target_component or 1, group, int(round(hz)), 1
                )
            )
            self.requests_sent += 1
        now = time.monotonic()
        for name in wanted:
            self._last_request[name] = now

    async def _monitor_until_woken(self) -> None:
        """Every `check_interval`, re-request messages far below their rate, rate-limited."""
        while True:
            try:
                async with asyncio.timeout(self.check_interval):
                    await self._wake.wait()
                return
            except TimeoutError:
                pass
            if self.link.state != LinkState.CONNECTED:
                continue
            achieved = self.link.stats.rates()
            now = time.monotonic()
            starved = {
                name: hz
                for name, hz in self.requested.items()
                if achieved.get(name, 0.0) < 0.5 * hz
                and achieved.get(name, 0.0) > 0.0  # never sent at all: the vehicle lacks it
                and now - self._last_request.get(name, 0.0) >= self.retry_interval
            }
            if not starved:
                continue
            if self.method == "SET_MESSAGE_INTERVAL":
                sub = self.link.bus.subscribe("stream-reacks", types=["COMMAND_ACK"], maxlen=50)
                try:
                    for name, hz in starved.items():
                        await self._set_interval(name, hz, sub, attempts=1)
                finally:
                    sub.close()
            else:
                self._request_streams(starved)

    def snapshot(self) -> StreamsSnapshot:
        """Requested vs achieved rates per message, as a field engineer reads them."""
        achieved = self.link.stats.rates()
        rows = {}
        for name, hz in self.requested.items():
            got = achieved.get(name, 0.0)
            rows[name] = StreamRate(hz, round(got, 2), round(got / hz, 3) if hz else None, self.acks.get(name))
        return StreamsSnapshot(self.method, self.requests_sent, rows)


def _family(autopilot: int) -> str | None:
    if autopilot == mavlink.MAV_AUTOPILOT_PX4:
        return "PX4"
    if autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA:
        return "ArduPilot"
    return None


def enum_result(value: int) -> str:
    entry = mavlink.enums["MAV_RESULT"].get(value)
    return entry.name.removeprefix("MAV_RESULT_") if entry else str(value)
