"""Ask the vehicle for what the estimators need, negotiate each message's rate, and check what
actually arrives.

Two mechanisms exist in the field:
- MAV_CMD_SET_MESSAGE_INTERVAL, per message, ACKed (ArduPilot 4.x, PX4);
- REQUEST_DATA_STREAM, per group of messages, never ACKed (APM 2.5 / ArduPilot 3.x, where
  ArduCopter sends nothing until asked).
The negotiation is per message (docs/vehicles.md, "Stream requests"): each message is asked for
by SET_MESSAGE_INTERVAL; a refused rate (DENIED, or FAILED for being too fast) is retried at the
highest rate the vehicle allows — read from its STATUSTEXT reason (ArduPilot's "too fast.
Increase SCHED_LOOP_RATE": 0.8 × SCHED_LOOP_RATE, read from the vehicle) or else a step down a
ladder of rates; only a message refused at every rate falls back to its REQUEST_DATA_STREAM
group, and the accepted group-mates are then asked again so the group request does not override
them.
A vehicle that does not know the command (no ACK, UNSUPPORTED) gets REQUEST_DATA_STREAM for all.
Requests are repeated only after a reconnect, a reboot, or when a message stays far below its
accepted rate or stops after it had arrived (another ground station may have overridden it, or a
reboot quicker than the heartbeat timeout forgot it); a group always at the rates of its accepted
members, a message at most once per `retry_interval`, doubled after each re-request that did not
bring it back (up to MAX_BACKOFF): never a flood of requests over a slow radio (docs/vehicles.md).

Each message's target rate passes through `target_rate(name, hz)` before it is asked for: the one
place where a per-message cap (a radio's budget) applies.
"""

from __future__ import annotations

import asyncio
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from gcs.mavlink.command_ack import answers
from gcs.mavlink.dialect import mavlink
from gcs.mavlink.params import param_name
from gcs.mavlink.statustext import CHUNK_CHARS
from gcs.runtime.link import GCS_COMPID, GCS_SYSID, Link, LinkState
from gcs.runtime.snapshots import StreamRate, StreamsSnapshot

SET_MESSAGE_INTERVAL = "SET_MESSAGE_INTERVAL"
REQUEST_DATA_STREAM = "REQUEST_DATA_STREAM"

#: REQUEST_DATA_STREAM group of each message, as ArduPilot assigns them.
STREAM_GROUPS = {
    "RAW_IMU": mavlink.MAV_DATA_STREAM_RAW_SENSORS,
    "SCALED_IMU2": mavlink.MAV_DATA_STREAM_RAW_SENSORS,
    "SCALED_PRESSURE": mavlink.MAV_DATA_STREAM_RAW_SENSORS,
    "GPS_RAW_INT": mavlink.MAV_DATA_STREAM_EXTENDED_STATUS,
    "SYS_STATUS": mavlink.MAV_DATA_STREAM_EXTENDED_STATUS,
    "ATTITUDE": mavlink.MAV_DATA_STREAM_EXTRA1,
    "AHRS2": mavlink.MAV_DATA_STREAM_EXTRA1,
    "SIMSTATE": mavlink.MAV_DATA_STREAM_EXTRA1,
    "AHRS": mavlink.MAV_DATA_STREAM_EXTRA3,
    "EKF_STATUS_REPORT": mavlink.MAV_DATA_STREAM_EXTRA3,
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
        "SYS_STATUS",
        "EKF_STATUS_REPORT",
        "ESTIMATOR_STATUS",
    )
}

#: Rates tried, highest first, below a refused one when the vehicle does not say its limit
#: (divisors of the usual 400/300/50 Hz scheduler loops).
STEP_DOWN_HZ = (200.0, 100.0, 80.0, 50.0, 40.0, 25.0, 20.0, 10.0, 5.0, 2.0, 1.0)
#: ArduPilot refuses an interval shorter than 1/(0.8 · SCHED_LOOP_RATE) with this STATUSTEXT
#: (GCS_MAVLINK::set_message_interval): the vehicle's own limit is then 0.8 × its loop rate.
TOO_FAST = re.compile(r"too fast", re.IGNORECASE)
LOOP_RATE_FRACTION = 0.8
#: How long a STATUSTEXT may follow its refused COMMAND_ACK (ArduPilot queues the text).
REASON_WAIT = 0.5
#: Why a message asked for shows 0 Hz when it never came (`StreamNegotiator._lacks`).
NOT_SENT = "none arrived since it was asked for: the vehicle does not send it, or not yet"
#: The longest wait between re-requests of one message, in `retry_interval`s: each re-request
#: that did not bring it back doubles the wait, up to this.
MAX_BACKOFF = 8


@dataclass
class StreamPlan:
    """Rates in Hz wanted for the estimators and the comparison."""

    imu_hz: float = 50.0
    attitude_hz: float = 50.0
    gps_hz: float = 5.0
    aux_hz: float = 5.0  # barometer and onboard-AHRS health
    status_hz: float = 1.0  # SYS_STATUS: battery and sensor health for the vehicle panel
    #: EKF_STATUS_REPORT (ArduPilot): whether the vehicle's attitude is trustworthy yet, which
    #: names ATTITUDE's reference (gcs.mavlink.sampling: onboard or onboard-unready) and fills the
    #: panel's EKF row. A vehicle behind a radio may stream none unless asked (SRx_EXTRA3 0).
    #: PX4's ESTIMATOR_STATUS (0.5 Hz by default) fills that row too, at the same rate; it names no
    #: reference: PX4's EKF2 publishes no attitude while its own is not valid.
    ekf_hz: float = 1.0

    def for_autopilot(self, autopilot: str | None, mavlink_version: int | None = None) -> dict[str, float]:
        """The rates wanted from a vehicle of this family. EKF_STATUS_REPORT is not asked of an
        ArduPilot speaking MAVLink 1 only: ArduPilot before 3.5, the APM 2.5's firmware, whose
        DCM-only build has no EKF to report on (a 0 Hz "none arrived" row it cannot fix); an old
        board that has one still sends it with its EXTRA3 group, asked for AHRS."""
        if autopilot == "PX4":
            return {
                "HIGHRES_IMU": self.imu_hz,
                "ATTITUDE": self.attitude_hz,
                "GPS_RAW_INT": self.gps_hz,
                "SYS_STATUS": self.status_hz,
                "ESTIMATOR_STATUS": self.ekf_hz,
            }
        ekf = {"EKF_STATUS_REPORT": self.ekf_hz} if mavlink_version != 1 else {}
        return {
            "RAW_IMU": self.imu_hz,
            "SCALED_IMU2": self.imu_hz,
            "ATTITUDE": self.attitude_hz,
            "AHRS2": self.attitude_hz,
            "SIMSTATE": self.attitude_hz,
            "GPS_RAW_INT": self.gps_hz,
            "SCALED_PRESSURE": self.aux_hz,
            "AHRS": self.aux_hz,
            "SYS_STATUS": self.status_hz,
            **ekf,
        }


@dataclass
class Negotiated:
    """What was agreed for one message: asked `requested_hz`, the vehicle `accepted_hz` through
    `method`; `ack` is the last COMMAND_ACK result, `reason` why the two rates differ."""

    requested_hz: float
    accepted_hz: float | None = None
    method: str | None = None
    ack: str | None = None
    reason: str | None = None


@dataclass
class StreamRequester:
    link: Link
    plan: StreamPlan = field(default_factory=StreamPlan)
    ack_timeout: float = 1.0
    retry_interval: float = 10.0
    check_interval: float = 5.0
    method: str | None = None  # SET_MESSAGE_INTERVAL, REQUEST_DATA_STREAM, or "mixed" once decided
    requested: dict[str, float] = field(default_factory=dict)
    negotiated: dict[str, Negotiated] = field(default_factory=dict)
    requests_sent: int = 0
    autopilot: str | None = None
    #: the radio's budget (gcs.runtime.radio.RadioGovernor.cap): wanted rates → rates to request
    rate_cap: Callable[[dict[str, float]], dict[str, float]] | None = None
    #: the vehicle's SCHED_LOOP_RATE once read (after a "too fast" refusal)
    loop_rate_hz: float | None = None
    _wake: asyncio.Event = field(default_factory=asyncio.Event)
    _last_request: dict[str, float] = field(default_factory=dict)
    #: messages seen arriving since they were last asked for: one that then stops has been forgotten
    #: (one never seen the vehicle lacks, and is not asked for again)
    _arrived: set[str] = field(default_factory=set)
    #: re-requests in a row per message that did not bring it back to half its accepted rate
    _misses: dict[str, int] = field(default_factory=dict)
    _no_intervals: bool = False  # the vehicle does not know SET_MESSAGE_INTERVAL

    @property
    def acks(self) -> dict[str, str]:
        return {name: n.ack for name, n in self.negotiated.items() if n.ack is not None}

    def _on_link_state(self, old: LinkState, new: LinkState) -> None:
        if new == LinkState.CONNECTED:
            self.request_again()

    def request_again(self) -> None:
        """Re-request everything soon (after a reconnect or a reboot)."""
        self._wake.set()

    def target_rate(self, name: str, hz: float) -> float:
        """The rate to ask for `name` given the plan's `hz`: the hook for a per-message cap."""
        return hz

    async def run(self) -> None:
        self.link.state_changed.connect(self._on_link_state)
        replies = self.link.bus.subscribe(
            "stream-acks", types=["COMMAND_ACK", "HEARTBEAT", "STATUSTEXT", "PARAM_VALUE"], maxlen=500
        )
        try:
            while True:
                await self.link.wait_connected()
                self._wake.clear()
                await self._request_all(replies)
                await self._monitor_until_woken()
        finally:
            replies.close()

    async def _request_all(self, replies) -> None:
        self.autopilot = await self._autopilot(replies)
        plan = self.plan.for_autopilot(self.autopilot, self.link.vehicle_mavlink)
        wanted = {name: self.target_rate(name, hz) for name, hz in plan.items()}
        if self.rate_cap is not None:  # the radio's budget
            wanted = self.rate_cap(wanted)
        self.negotiated = {name: Negotiated(hz) for name, hz in wanted.items()}
        self._misses.clear()
        if not self._no_intervals:
            for name, hz in wanted.items():
                result = await self._negotiate(name, hz, replies)
                if result in ("NO_ACK", "UNSUPPORTED") and all(
                    n.method is None for n in self.negotiated.values()
                ):  # the command itself is unknown to this vehicle: no use asking per message
                    self._no_intervals = self.autopilot != "PX4"
                    break
        refused = {name: hz for name, hz in wanted.items() if self.negotiated[name].method is None}
        if refused and self.autopilot != "PX4":
            self._request_streams(refused)
            for name in refused:
                n = self.negotiated[name]
                n.method, n.accepted_hz = REQUEST_DATA_STREAM, min(wanted[name], self._group_rate(name, refused))
            await self._restore_group_mates(refused, replies)
        self.requested = wanted
        methods = {n.method for n in self.negotiated.values() if n.method is not None}
        self.method = methods.pop() if len(methods) == 1 else ("mixed" if methods else None)

    def _group_rate(self, name: str, refused: dict[str, float]) -> float:
        group = STREAM_GROUPS.get(name)
        return max((hz for other, hz in refused.items() if STREAM_GROUPS.get(other) == group), default=0.0)

    async def _restore_group_mates(self, refused: dict[str, float], replies) -> None:
        """A group request sets every message of the group (ArduPilot, the simulator): ask the
        group-mates that SET_MESSAGE_INTERVAL accepted for their own rates again."""
        groups = {STREAM_GROUPS.get(name) for name in refused}
        for name, n in self.negotiated.items():
            if n.method == SET_MESSAGE_INTERVAL and STREAM_GROUPS.get(name) in groups and n.accepted_hz:
                await self._set_interval(name, n.accepted_hz, replies, attempts=1)

    async def _negotiate(self, name: str, hz: float, replies) -> str:
        """SET_MESSAGE_INTERVAL at hz, then, while refused, at the highest rate the vehicle allows."""
        n = self.negotiated[name]
        result, text = await self._ask(name, hz, replies)
        first = result
        tried = {hz}
        while result in ("DENIED", "FAILED"):
            n.reason = f"{result} at {hz:g} Hz" + (f": {text}" if text else "")
            if result == "FAILED" and not (text and TOO_FAST.search(text)):
                break  # not about the rate (ArduPilot: a message it cannot send): no lower rate helps
            lower = await self._lower_rate(hz, text, tried, replies)
            if lower is None:
                break
            tried.add(lower)
            hz = lower
            result, text = await self._ask(name, hz, replies)
        if result == "ACCEPTED":
            n.method, n.accepted_hz = SET_MESSAGE_INTERVAL, hz
            if first != "ACCEPTED" and n.reason:
                n.reason += f"; accepted {hz:g} Hz"
        elif n.reason is None:
            n.reason = f"SET_MESSAGE_INTERVAL: {result}"
        return first

    async def _ask(self, name: str, hz: float, replies) -> tuple[str, str | None]:
        """(ACK result, the vehicle's STATUSTEXT about a refusal or None)."""
        result = await self._set_interval(name, hz, replies)
        if result not in ("DENIED", "FAILED"):
            return result, None
        deadline = time.monotonic() + REASON_WAIT
        reason: list[str] = []
        chunk_id = None  # MAVLink 2 splits a long text into 50-character chunks of one id
        while (item := await replies.get(timeout=max(deadline - time.monotonic(), 0.0))) is not None:
            if item.type != "STATUSTEXT" or item.sysid != self.link.target_system:
                continue
            text, text_id = _text(item.msg), getattr(item.msg, "id", 0)
            if not reason and (TOO_FAST.search(text) or f"ID {MESSAGE_IDS[name]} " in text):
                reason, chunk_id = [text], text_id
            elif reason and chunk_id and text_id == chunk_id:
                reason.append(text)
            else:
                continue
            if len(text) < CHUNK_CHARS:
                break
        return result, "".join(reason) or None

    async def _lower_rate(self, refused_hz: float, reason: str | None, tried: set[float], replies) -> float | None:
        """The next rate to try below refused_hz: the vehicle's own limit when its reason names
        the scheduler loop, else the next step of STEP_DOWN_HZ."""
        if reason and TOO_FAST.search(reason):
            if self.loop_rate_hz is None:
                self.loop_rate_hz = await self._read_loop_rate(replies)
            if self.loop_rate_hz:
                limit = round(LOOP_RATE_FRACTION * self.loop_rate_hz, 3)
                if limit < refused_hz and limit not in tried:
                    return limit
        return next((hz for hz in STEP_DOWN_HZ if hz < refused_hz and hz not in tried), None)

    async def _read_loop_rate(self, replies) -> float | None:
        """SCHED_LOOP_RATE from the vehicle (one PARAM_REQUEST_READ), None without an answer."""
        self.link.send(
            mavlink.MAVLink_param_request_read_message(
                self.link.target_system or 1, self.link.target_component or 1, b"SCHED_LOOP_RATE", -1
            )
        )
        deadline = time.monotonic() + self.ack_timeout
        while (item := await replies.get(timeout=max(deadline - time.monotonic(), 0.0))) is not None:
            if (
                item.type == "PARAM_VALUE"
                and item.sysid == self.link.target_system
                and param_name(item.msg) == "SCHED_LOOP_RATE"
            ):
                return float(item.msg.param_value) or None
        return None

    async def _autopilot(self, replies) -> str | None:
        """The autopilot family from the vehicle's heartbeat (waits briefly for one)."""
        deadline = time.monotonic() + 2.0
        for item in replies.drain():
            if item.type == "HEARTBEAT" and item.sysid == self.link.target_system:
                return _family(item.msg.autopilot)
        while (item := await replies.get(timeout=max(deadline - time.monotonic(), 0.0))) is not None:
            if item.type == "HEARTBEAT" and item.sysid == self.link.target_system:
                return _family(item.msg.autopilot)
        return None

    async def _set_interval(self, name: str, hz: float, replies, attempts: int = 2) -> str:
        interval_us = int(round(1e6 / hz)) if hz > 0 else -1
        command = mavlink.MAV_CMD_SET_MESSAGE_INTERVAL
        for _ in range(attempts):
            replies.drain()
            to = (self.link.target_system or 1, self.link.target_component or 1)
            self.link.send(
                mavlink.MAVLink_command_long_message(
                    *to,
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
            self._arrived.discard(name)
            deadline = time.monotonic() + self.ack_timeout
            while (item := await replies.get(timeout=max(deadline - time.monotonic(), 0.0))) is not None:
                if item.type == "COMMAND_ACK" and answers(
                    item.msg, (item.sysid, item.compid), command, to, (GCS_SYSID, GCS_COMPID)
                ):
                    result = enum_result(item.msg.result)
                    if name in self.negotiated:
                        self.negotiated[name].ack = result
                    return result
        if name in self.negotiated:
            self.negotiated[name].ack = "NO_ACK"
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
            self._arrived.discard(name)

    async def _monitor_until_woken(self) -> None:
        """Every `check_interval`, re-request messages far below their accepted rate or stopped after
        they had arrived, rate-limited."""
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
            self._arrived.update(name for name in self.negotiated if achieved.get(name, 0.0) > 0.0)
            if self._all_silent(achieved, now):
                return  # ask for everything again, as after a reconnect
            starved = {
                name: n
                for name, n in self.negotiated.items()
                if n.accepted_hz
                and self._starved(name, achieved.get(name, 0.0), n.accepted_hz)
                and now - self._last_request.get(name, 0.0) >= self._retry_wait(name)
            }
            for name, n in self.negotiated.items():
                if n.accepted_hz and achieved.get(name, 0.0) >= 0.5 * n.accepted_hz:
                    self._misses.pop(name, None)  # back: the next trouble is retried soon again
            for name in starved:
                self._misses[name] = self._misses.get(name, 0) + 1
            if not starved:
                continue
            if any(n.method == REQUEST_DATA_STREAM for n in starved.values()):
                self._request_streams(self._whole_groups(starved))
            sub = self.link.bus.subscribe("stream-reacks", types=["COMMAND_ACK"], maxlen=50)
            try:
                for name, n in starved.items():
                    if n.method == SET_MESSAGE_INTERVAL and n.accepted_hz:
                        await self._set_interval(name, n.accepted_hz, sub, attempts=1)
            finally:
                sub.close()

    def _whole_groups(self, starved: dict[str, Negotiated]) -> dict[str, float]:
        """The group-mates of the starved messages asked for by group, each at its accepted rate:
        a group request sets the rate of every message in the group, so asking one slow member's
        rate alone would slow its faster mates (and, behind a radio, see-saw against its budget)."""
        groups = {STREAM_GROUPS.get(name) for name, n in starved.items() if n.method == REQUEST_DATA_STREAM}
        return {
            name: n.accepted_hz or 0.0
            for name, n in self.negotiated.items()
            if n.method == REQUEST_DATA_STREAM and STREAM_GROUPS.get(name) in groups
        }

    def _retry_wait(self, name: str) -> float:
        """`retry_interval`, doubled after each re-request of `name` that did not bring it back: a
        message the vehicle (or a radio dropping it) will not send is asked for ever more rarely."""
        return self.retry_interval * min(2 ** self._misses.get(name, 0), MAX_BACKOFF)

    def _starved(self, name: str, achieved_hz: float, accepted_hz: float) -> bool:
        """Far below its accepted rate (the rate after the radio's cap: what was asked for), or
        stopped after it had arrived: not one packet over the whole rate window (another ground
        station reset it, or a quick reboot was asked for other streams since); never arrived at
        all: the vehicle lacks it."""
        return 0.0 < achieved_hz < 0.5 * accepted_hz or (achieved_hz == 0.0 and name in self._arrived)

    def _all_silent(self, achieved: dict[str, float], now: float) -> bool:
        """Every stream the vehicle accepted has stopped while its heartbeats go on, and none was
        asked for in the last `retry_interval`: the vehicle forgot the requests (a reboot quicker
        than the link's heartbeat timeout, or another ground station reset the rates)."""
        accepted = [name for name, n in self.negotiated.items() if n.accepted_hz]
        return bool(accepted) and all(
            achieved.get(name, 0.0) == 0.0 and now - self._last_request.get(name, 0.0) >= self.retry_interval
            for name in accepted
        )

    def snapshot(self) -> StreamsSnapshot:
        """Requested, accepted and achieved rates per message, and why they differ."""
        achieved = self.link.stats.rates()
        now = time.monotonic()
        rows = {}
        for name, n in self.negotiated.items():
            got = achieved.get(name, 0.0)
            hz = n.requested_hz
            reason = n.reason
            if reason is None and self._lacks(name, got, now):
                reason = NOT_SENT
            rows[name] = StreamRate(
                hz, round(got, 2), round(got / hz, 3) if hz else None, n.ack, n.accepted_hz, n.method, reason
            )
        return StreamsSnapshot(self.method, self.requests_sent, rows)

    def _lacks(self, name: str, achieved_hz: float, now: float) -> bool:
        """Accepted (or asked for by group, which nothing acknowledges), yet not one packet in the
        `retry_interval` since: the vehicle does not have it (an APM 2.5's second IMU, SCALED_IMU2)."""
        n = self.negotiated[name]
        last = self._last_request.get(name)
        return (
            bool(n.accepted_hz)
            and achieved_hz == 0.0
            and name not in self._arrived
            and last is not None
            and now - last >= self.retry_interval
        )


def _text(msg) -> str:
    raw = msg.text
    return (raw if isinstance(raw, str) else raw.decode(errors="replace")).rstrip("\x00")


def _family(autopilot: int) -> str | None:
    if autopilot == mavlink.MAV_AUTOPILOT_PX4:
        return "PX4"
    if autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA:
        return "ArduPilot"
    return None


def enum_result(value: int) -> str:
    entry = mavlink.enums["MAV_RESULT"].get(value)
    return entry.name.removeprefix("MAV_RESULT_") if entry else str(value)
