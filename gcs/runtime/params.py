"""The MAVLink parameter protocol, client side: download the whole table, read one, write one
and prove the vehicle stored it.

- A write is done only when the vehicle's PARAM_VALUE echo says so, resent up to `set_attempts` ×
  `reply_timeout`; an echo with another value is an error naming both values, never silence.
- A download is PARAM_REQUEST_LIST, then every missing index by PARAM_REQUEST_READ, `window` at a
  time, each a bounded number of times, until complete or the deadline; the error names what is missing.
- Integer parameters travel bytewise on PX4: AUTOPILOT_VERSION capabilities decide, else the autopilot.
Every PARAM_VALUE updates the table, including replies to other clients behind a forwarding output.
Why each rule exists (other ground stations, failures in the field): docs/vehicles.md
"""

from __future__ import annotations

import asyncio
import difflib
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from gcs.mavlink.command_ack import answers
from gcs.mavlink.dialect import mavlink
from gcs.mavlink.identity import ARDUPILOT_SYSID_PARAMS
from gcs.mavlink.params import (
    ParamError,
    check_name,
    decode,
    encode,
    format_value,
    param_name,
    same_value,
    type_name,
    value_bytes,
)
from gcs.runtime.bus import MessageBus, Subscription
from gcs.runtime.events import EventLog
from gcs.runtime.link import GCS_COMPID, GCS_SYSID, Link
from gcs.runtime.vehicle import VehicleState
from gcs.runtime.vehicle_link import VehicleLink

#: PARAM_VALUE.param_index of a value that is not part of a list (ArduPilot's set echo: -1).
_NO_INDEX = 65535


class ParamTimeout(ParamError):
    """The vehicle did not answer (link down, unknown name, or too many packets lost)."""


class ParamMismatch(ParamError):
    """The vehicle answered a write with a different value than asked."""

    def __init__(self, name: str, asked: float, stored: float) -> None:
        super().__init__(f"{name}: vehicle stored {format_value(stored)}, asked {format_value(asked)}")
        self.name, self.asked, self.stored = name, asked, stored


class UnknownParam(ParamError):
    pass


@dataclass(frozen=True, slots=True)
class ParamRow:
    """One parameter as files, the API and the page show it (the type by name: "REAL32")."""

    name: str
    value: int | float
    type: str
    index: int | None


@dataclass(frozen=True, slots=True)
class Param:
    """One parameter as the vehicle last reported it: value is an int for integer types."""

    name: str
    value: int | float
    type: int
    index: int | None = None

    def snapshot(self) -> ParamRow:
        return ParamRow(self.name, self.value, type_name(self.type), self.index)


class ParamClient:
    """The parameter table of the link's vehicle and the protocol to read and write it.

    Run `run()` as a task (Station does); then `download()`, `read()`, `set()`.
    `events`: where every write is recorded (kind "param": name, old, new, asked, verified), and
    every new value the vehicle reports of a parameter already known (kind "param value": name,
    old, new), whoever changed it: this station, another ground station behind a forwarding
    output, or the vehicle itself. Pages follow these to show a value as soon as it changes.
    """

    def __init__(
        self,
        link: Link,
        vehicle: VehicleState,
        events: EventLog | None = None,
        *,
        reply_timeout: float = 1.0,
        set_attempts: int = 3,
        read_attempts: int = 5,
        list_attempts: int = 3,
        list_gap: float = 1.0,
        window: int = 8,
        version_timeout: float = 1.0,
    ) -> None:
        self.link = link
        self.vehicle = vehicle
        self.events = events if events is not None else EventLog()
        self.reply_timeout = reply_timeout
        self.set_attempts = set_attempts
        self.read_attempts = read_attempts
        self.list_attempts = list_attempts
        self.list_gap = list_gap
        self.window = window
        self.version_timeout = version_timeout
        self.table: dict[str, Param] = {}
        self.count: int | None = None
        self.complete = False
        self.capabilities: int | None = None
        self._progress: dict = {"state": "idle"}
        self._received: dict[int, str] = {}  # index → name, for the download in progress
        self._waiters: list[tuple[Callable[[Param], bool], asyncio.Future]] = []
        self._version_answer = asyncio.Event()
        self._version_asked = False
        self._running = False
        self._write_lock = asyncio.Lock()
        self._download_lock = asyncio.Lock()
        #: while a write of the vehicle's own system id runs: the id asked (gcs.runtime.fleet follows)
        self.renaming_to: int | None = None

    # ---- state ------------------------------------------------------------------------
    @property
    def bytewise(self) -> bool:
        """Integer parameters travel bytewise: from AUTOPILOT_VERSION, else PX4 does, ArduPilot not."""
        caps = self.capabilities if self.capabilities is not None else self.vehicle.capabilities
        if caps is not None:
            return bool(caps & mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE)
        return self.vehicle.autopilot == "PX4"

    def values(self) -> dict[str, int | float]:
        """Name → value of every parameter known now (a snapshot for files and recordings)."""
        return {name: p.value for name, p in sorted(self.table.items())}

    def progress(self) -> dict:
        """The current or last download: state idle|downloading|complete|incomplete, counts."""
        out = dict(self._progress)
        if out["state"] == "downloading":
            out["received"] = len(self._received)
            out["count"] = self.count
            out["elapsed_s"] = round(time.monotonic() - out["started"], 3)
        out.pop("started", None)
        return out

    # ---- the receive side ---------------------------------------------------------------
    async def run(self) -> None:
        sub = self.link.bus.subscribe("params", types=["PARAM_VALUE", "AUTOPILOT_VERSION", "COMMAND_ACK"], maxlen=5000)
        self._running = True
        try:
            async for item in sub:
                if item.sysid != self.link.target_system:
                    continue
                if item.type == "PARAM_VALUE" and item.compid == self.link.target_component:
                    self._on_value(item.msg)
                elif item.type == "AUTOPILOT_VERSION":
                    self.capabilities = item.msg.capabilities
                    self._version_answer.set()
                elif (
                    item.type == "COMMAND_ACK"
                    and answers(
                        item.msg,
                        (item.sysid, item.compid),
                        mavlink.MAV_CMD_REQUEST_MESSAGE,
                        self._target(),
                        (GCS_SYSID, GCS_COMPID),
                    )
                    and item.msg.result != mavlink.MAV_RESULT_ACCEPTED
                ):
                    self._version_answer.set()
        finally:
            self._running = False
            sub.close()

    def _on_value(self, msg) -> None:
        name = param_name(msg)
        if name == "_HASH_CHECK":  # PX4's table hash, not a parameter
            return
        raw = value_bytes(msg)
        index = msg.param_index if msg.param_index != _NO_INDEX and msg.param_index < msg.param_count else None
        known = self.table.get(name)
        if index is None and known is not None:
            index = known.index
        param = Param(name, decode(raw, msg.param_type, self.bytewise), msg.param_type, index)
        self.table[name] = param
        if known is not None and not same_value(known.value, param.value):
            self.events.record("param value", "vehicle", name=name, old=known.value, new=param.value)
        if msg.param_index != _NO_INDEX:
            self.count = msg.param_count
            if index is not None and self._progress["state"] == "downloading":
                self._received[index] = name
        for waiter in list(self._waiters):
            predicate, future = waiter
            if not future.done() and predicate(param):
                future.set_result(param)

    async def _expect(self, predicate: Callable[[Param], bool], timeout: float) -> Param | None:
        """The next PARAM_VALUE matching predicate within timeout s, else None."""
        future = asyncio.get_running_loop().create_future()
        waiter = (predicate, future)
        self._waiters.append(waiter)
        try:
            async with asyncio.timeout(max(timeout, 0.0)):  # not wait_for: see MessageBus.get
                return await future
        except TimeoutError:
            return None
        finally:
            self._waiters.remove(waiter)

    async def _ready(self) -> None:
        """Connected, and the encoding known (AUTOPILOT_VERSION asked for once)."""
        if not self._running:
            raise ParamError("the parameter client is not running (start Station first)")
        if not await self.link.wait_connected(10.0):
            down = self.link.down_reason(0.0)
            raise ParamTimeout(
                f"no heartbeat from a vehicle on {self.link.address} within 10 s"
                + (f"; the link is lost: {down}" if down else "")
            )
        if self.capabilities is None and not self._version_asked:
            self._version_asked = True
            self._send(
                mavlink.MAVLink_command_long_message(
                    *self._target(),
                    mavlink.MAV_CMD_REQUEST_MESSAGE,
                    0,
                    mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
                    0,
                    0,
                    0,
                    0,
                    0,
                    0,
                )
            )
            try:
                async with asyncio.timeout(self.version_timeout):
                    await self._version_answer.wait()
            except TimeoutError:
                pass  # old firmware: the autopilot type decides

    def _target(self) -> tuple[int, int]:
        return self.link.target_system or 1, self.link.target_component or 1

    def _send(self, msg) -> None:
        self.link.send(msg)

    def request(self, names: Iterable[str]) -> None:
        """Ask for these parameters without waiting; the answers update the table (and reach
        every bus subscriber, such as the estimation, as PARAM_VALUE)."""
        for name in names:
            self._send(mavlink.MAVLink_param_request_read_message(*self._target(), name.encode(), -1))

    # ---- operations ---------------------------------------------------------------------
    async def read(self, name: str) -> Param:
        """Ask the vehicle for one parameter by name; retried `read_attempts` × `reply_timeout`."""
        check_name(name)
        if self.complete and name not in self.table:
            raise UnknownParam(unknown_message(name, self.table))
        await self._ready()
        asked = time.monotonic()
        for _ in range(self.read_attempts):
            self._check_link(asked, f"{name}: no answer")
            self._send(mavlink.MAVLink_param_request_read_message(*self._target(), name.encode(), -1))
            param = await self._expect(lambda p: p.name == name, self.reply_timeout)
            if param is not None:
                return param
        self._check_link(asked, f"{name}: no answer")
        raise ParamTimeout(
            f"{name}: no answer after {self.read_attempts} requests × {self.reply_timeout} s "
            f"(not a parameter of this vehicle, or the link is down)"
        )

    async def set(self, name: str, value: float, client: str = "cli") -> Param:
        """Write one parameter and return what the vehicle stored, verified by its echo.

        Raises ParamMismatch when the vehicle keeps answering another value, ParamTimeout when it
        does not answer; the event log gets the write either way."""
        check_name(name)
        async with self._write_lock:
            await self._ready()
            current = self.table.get(name) or await self.read(name)
            wire, asked = encode(name, value, current.type, self.bytewise)
            reply = None
            written = time.monotonic()
            renamed = self._echo_as_new_system(name, asked)
            try:
                for _ in range(self.set_attempts):
                    self._send(mavlink.MAVLink_param_set_message(*self._target(), name.encode(), wire, current.type))
                    reply = await self._expect(lambda p: p.name == name, self.reply_timeout)
                    if reply is not None and same_value(reply.value, asked):
                        break
            finally:
                if renamed is not None:
                    renamed.cancel()
                    self.renaming_to = None
            verified = reply is not None and same_value(reply.value, asked)
            down = None if reply is not None else self.link.down_reason(written)
            self.events.record(
                "param",
                client,
                name=name,
                old=current.value,
                new=None if reply is None else reply.value,
                asked=asked,
                verified=verified,
            )
            if reply is None:
                raise ParamTimeout(
                    f"{name}: no echo after {self.set_attempts} writes × {self.reply_timeout} s"
                    + (f" (the link was lost: {down})" if down else "")
                    + "; the value on the vehicle is unknown"
                )
            if not verified:
                raise ParamMismatch(name, asked, reply.value)
            return reply

    def _echo_as_new_system(self, name: str, asked: float) -> asyncio.Task | None:
        """ArduPilot takes a new MAV_SYSID (SYSID_THISMAV) at once and echoes the write as that
        system, which this client, following the old id, never hears: a write that worked read
        "no echo, the value on the vehicle is unknown" (and its event `verified: false`). While
        such a write runs, the echo is also taken from the asked system on the link itself (every
        vehicle's messages pass there, a fleet's view gets only its own). PX4's MAV_SYS_ID applies
        at reboot: its echo comes from the old id, as for any parameter."""
        if name not in ARDUPILOT_SYSID_PARAMS or asked == self.link.target_system or not 1 <= asked <= 255:
            return None
        self.renaming_to = int(asked)
        heard_on = self.link.link if isinstance(self.link, VehicleLink) else self.link
        bus: MessageBus = heard_on.bus if heard_on is not None else self.link.bus
        sub = bus.subscribe("params-new-sysid", types=["PARAM_VALUE"], maxlen=100)
        return asyncio.get_running_loop().create_task(self._take_echoes(sub, int(asked), name))

    async def _take_echoes(self, sub: Subscription, sysid: int, name: str) -> None:
        try:
            async for item in sub:
                if item.sysid == sysid and item.compid == self.link.target_component and param_name(item.msg) == name:
                    self._on_value(item.msg)
        finally:
            sub.close()

    async def download(self, timeout: float = 120.0) -> dict[str, Param]:
        """Fetch the whole table; ParamTimeout lists what is missing when it cannot complete."""
        async with self._download_lock:
            await self._ready()
            start = time.monotonic()
            deadline = start + timeout
            self._received = {}
            self.count = None
            self.complete = False
            self._progress = {"state": "downloading", "started": start, "list_requests": 0, "read_requests": 0}
            try:
                await self._request_list(start, deadline)
                await self._fill_missing(start, deadline)
            except ParamTimeout as exc:
                down = self.link.down_reason(start)  # the cause, whichever wait ran out first
                error = ParamTimeout(self._cut_short(down)) if down else exc
                self._failed(start, error)
                raise error from None
            except ParamError as exc:
                self._failed(start, exc)
                raise
            names = set(self._received.values())
            self.table = {name: p for name, p in self.table.items() if name in names}
            self.complete = True
            self._progress = {
                "state": "complete",
                "received": len(names),
                "count": self.count,
                "missing": [],
                "elapsed_s": round(time.monotonic() - start, 3),
                "list_requests": self._progress["list_requests"],
                "read_requests": self._progress["read_requests"],
            }
            return dict(self.table)

    def _failed(self, start: float, error: ParamError) -> None:
        """The download's progress once it stopped short with `error` (kept for the page)."""
        self._progress = {
            "state": "incomplete",
            "received": len(self._received),
            "count": self.count,
            "missing": self._missing()[:50],
            "error": str(error),
            "elapsed_s": round(time.monotonic() - start, 3),
            "list_requests": self._progress["list_requests"],
            "read_requests": self._progress["read_requests"],
        }

    def _cut_short(self, down: str) -> str:
        """A download stopped by a lost link, as the person reads it: the link, then how far it got."""
        of = "?" if self.count is None else str(self.count)
        return f"parameter download cut short: the link was lost ({down}); {len(self._received)} of {of} received"

    def _check_link(self, since: float, what: str) -> None:
        """Stop waiting for an answer the moment the link's transport has closed since `since` (a
        serial port gone; ParamTimeout naming why): retries and timeouts would only add seconds to
        a generic failure. A link lost for silence alone (a radio fade) is waited out."""
        down = self.link.closed_since(since)
        if down is not None:
            raise ParamTimeout(f"{what}: the link was lost ({down})")

    def _missing(self) -> list[int]:
        return [] if self.count is None else [i for i in range(self.count) if i not in self._received]

    async def _request_list(self, since: float, deadline: float) -> None:
        """PARAM_REQUEST_LIST (repeated if nothing comes), then follow the stream until it ends:
        the last index arrived, or nothing for `list_gap` s."""
        for _ in range(self.list_attempts):
            self._check_link(since, "parameter download")
            self._send(mavlink.MAVLink_param_request_list_message(*self._target()))
            self._progress["list_requests"] += 1
            if await self._expect(
                lambda p: self.count is not None, min(2 * self.reply_timeout, deadline - time.monotonic())
            ):
                break
        else:
            raise ParamTimeout(
                f"no PARAM_VALUE after {self.list_attempts} PARAM_REQUEST_LIST × {2 * self.reply_timeout} s"
            )
        while self._missing() and ((self.count or 0) - 1) not in self._received:
            self._check_link(since, "parameter download")
            gap = min(self.list_gap, deadline - time.monotonic())
            if await self._expect(lambda p: True, gap) is None:
                return

    async def _fill_missing(self, since: float, deadline: float) -> None:
        """Re-request missing indices, `window` outstanding at a time, each `read_attempts` times."""
        tries: dict[int, int] = {}
        pending: dict[int, float] = {}  # index → when its reply is overdue
        while missing := self._missing():
            self._check_link(since, "parameter download")
            now = time.monotonic()
            if now > deadline:
                raise ParamTimeout(incomplete_message(missing, self.count, "deadline reached"))
            pending = {i: t for i, t in pending.items() if t > now and i not in self._received}
            ready = [i for i in missing if i not in pending and tries.get(i, 0) < self.read_attempts]
            if not ready and not pending:
                raise ParamTimeout(incomplete_message(missing, self.count, f"each asked {self.read_attempts} times"))
            for i in ready[: self.window - len(pending)]:
                self._send(mavlink.MAVLink_param_request_read_message(*self._target(), b"", i))
                self._progress["read_requests"] += 1
                tries[i] = tries.get(i, 0) + 1
                pending[i] = now + self.reply_timeout
            await self._expect(lambda p: True, min(min(pending.values()), deadline) - now)


def unknown_message(name: str, known) -> str:
    close = difflib.get_close_matches(name.upper(), list(known), n=3)
    hint = f"; did you mean {', '.join(close)}?" if close else ""
    return f"the vehicle has no parameter {name}{hint}"


def incomplete_message(missing: list[int], count: int | None, why: str) -> str:
    shown = ", ".join(map(str, missing[:20])) + (" ..." if len(missing) > 20 else "")
    return f"parameter download incomplete ({why}): {len(missing)} of {count} missing, indices {shown}"
