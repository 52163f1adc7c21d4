"""SimVehicle: a scripted vehicle with known truth that speaks real MAVLink to a ground station.

Everything happens on the vehicle clock (s since boot). `advance(t)` steps that clock to t and
returns the encoded packets due, with no I/O and no wall clock, so tests and soak runs are
deterministic and run as fast as the CPU allows; `run(address)` paces `advance` against the wall
clock (times `speed`) and moves the bytes over a transport.

Scheduling is deadline based: a stream at r Hz started at t0 sends its k-th message at exactly
t0 + k/r, so rates have no drift. The autopilot loop (filters) and the GPS (5 Hz) are events on
the same timeline. Equal deadlines go in a fixed order, so the same seed gives the same bytes.
"""

from __future__ import annotations

import asyncio
import heapq
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from gcs.mavlink.dialect import MARKER_V2, Encoder, mavlink
from gcs.mavlink.signing import Signing
from gcs.sim.autopilot import GPS_RATE_HZ, Autopilot
from gcs.sim.dataflash import FlightLog
from gcs.sim.logserver import SEND_LOOP_HZ, LogServer, LogStore
from gcs.sim.motion import Truth, make_script
from gcs.sim.params import ParamServer, ParamTable
from gcs.sim.profiles import Profile, get_profile
from gcs.sim.pty import PtyTransport
from gcs.sim.radio import SikRadio
from gcs.sim.sensors import Home, SensorFaults, home_declination
from gcs.transport.pipes import make_transport

#: The vehicle parameters that hold the declination (left out with publish_declination=False).
DECLINATION_PARAMS = ("COMPASS_DEC", "EKF2_MAG_DECL")
#: Internal events, ordered before messages due at the same instant.
_GPS, _LOOP, _LOGS = "_gps", "_loop", "_logs"
#: Wall-clock lag (s) after which run() stops catching up and lets the vehicle clock slip.
MAX_CATCH_UP = 1.0


@dataclass
class _Stream:
    """One periodic event: k-th occurrence at start + k / rate; `generation` voids stale heap entries."""

    name: str
    order: int
    rate: float = 0.0
    start: float = 0.0
    k: int = 0
    generation: int = 0


class SimVehicle:
    """A simulated autopilot. See the module docstring; profile/script names in gcs.sim.profiles
    and gcs.sim.motion. `faults`: the sensor errors; the sensor models read the same object, so
    assigning its fields later changes them at run time; a `faults.declination` of None becomes
    the World Magnetic Model's at `home`. `param_drop` / `param_clamp`: parameter protocol faults,
    also settable later through the properties of the same names. `publish_declination=False`:
    the vehicle has no COMPASS_DEC / EKF2_MAG_DECL parameter (a ground station must find the
    declination itself; the onboard filters still use the true one)."""

    def __init__(
        self,
        profile: str = "pixhawk",
        script: str = "bench",
        seed: int = 0,
        faults: SensorFaults | None = None,
        speed: float = 1.0,
        sysid: int = 1,
        compid: int = 1,
        home: Home | None = None,
        param_drop: float = 0.0,
        param_clamp: dict[str, float] | None = None,
        publish_declination: bool = True,
        interval_limits: dict[str, float] | None = None,
        signing_key: bytes | None = None,
    ) -> None:
        self.profile: Profile = get_profile(profile)
        self.script = make_script(script)
        self.faults = faults if faults is not None else SensorFaults()
        self.seed, self.speed, self.sysid, self.compid = seed, speed, sysid, compid
        self.home = home or Home()
        if self.faults.declination is None:  # the real field at home (World Magnetic Model)
            self.faults.declination = home_declination(self.home)
        rows = self.profile.param_rows()
        if not publish_declination:  # a vehicle that does not tell its declination (see docs)
            rows = [row for row in rows if row[0] not in DECLINATION_PARAMS]
        self.params = ParamTable(rows, bytewise=self.profile.param_bytewise)
        if "COMPASS_DEC" in self.params:  # ArduPilot: radians
            self.params["COMPASS_DEC"] = self.faults.declination
        if "EKF2_MAG_DECL" in self.params:  # PX4: degrees
            self.params["EKF2_MAG_DECL"] = math.degrees(self.faults.declination)
        for name in ("SYSID_THISMAV", "MAV_SYS_ID"):  # the vehicle's own system id, as it reports it
            if name in self.params:
                self.params[name] = sysid
        param_seed, autopilot_seed, log_seed = np.random.SeedSequence(seed).spawn(3)
        self.autopilot = Autopilot(self.profile, self.script, self.faults, self.params, autopilot_seed, self.home)
        self.param_server = ParamServer(
            self.params,
            np.random.default_rng(param_seed),
            drop=param_drop,
            clamp=param_clamp,
            on_change=self.autopilot.apply_param,
        )
        #: the onboard DataFlash logs and the log protocol (gcs.sim.logserver)
        self.logs = LogStore(self._new_flight_log)
        self.log_server = LogServer(self.logs, np.random.default_rng(log_seed))
        self._encoder = Encoder(sysid, compid, mavlink1=self.profile.mavlink1)
        #: message → highest SET_MESSAGE_INTERVAL rate (Hz); faster is DENIED with ArduPlane's
        #: STATUSTEXT (its 0.8 × SCHED_LOOP_RATE limit), e.g. {"RAW_IMU": 40.0}
        self.interval_limits = dict(interval_limits or {})
        #: packets refused for a missing or bad MAVLink 2 signature while signing is on
        self.signature_rejected = 0
        self._text_id = 0  # STATUSTEXT.id of the last chunked text
        self.signing_key: bytes | None = None
        self._parser = mavlink.MAVLink(None)
        if signing_key is not None:
            self.set_signing_key(signing_key)
        self._parser.robust_parsing = True
        self.t = 0.0
        self._outbox: list[bytes] = []
        self._heap: list[tuple[float, int, int, _Stream]] = []
        self._streams: dict[str, _Stream] = {}
        for order, name in enumerate((_GPS, _LOOP, _LOGS) + self.profile.messages):
            self._streams[name] = _Stream(name, order)
        self._group_rates: dict[int, float] = {}
        self._overrides: dict[str, float] = {}  # SET_MESSAGE_INTERVAL, Hz (0 = off)
        self._set_rate(_GPS, GPS_RATE_HZ)
        self._set_rate(_LOOP, self.profile.loop_hz)
        self._set_rate(_LOGS, SEND_LOOP_HZ)
        self._set_rate("HEARTBEAT", 1.0)
        self._update_rates()
        self.radio: SikRadio | None = None  # set by gcs.sim.radio.fit_radio
        self.received: dict[str, int] = {}  # messages accepted from ground stations, by type
        self.rejected = 0  # of those, how many had parameters the vehicle could not use

    # --- public --------------------------------------------------------------------------------

    @property
    def armed(self) -> bool:
        return self.autopilot.armed

    def truth(self, t: float) -> Truth:
        """The true state at vehicle time t (s)."""
        return self.script.truth(t)

    @property
    def param_drop(self) -> float:
        """Fraction of PARAM_VALUE packets silently lost (seeded); settable at run time."""
        return self.param_server.drop

    @param_drop.setter
    def param_drop(self, fraction: float) -> None:
        self.param_server.drop = fraction

    @property
    def param_clamp(self) -> dict[str, float]:
        """Parameter name → largest value the vehicle will store; edit in place at run time."""
        return self.param_server.clamp

    def stream_rates(self) -> dict[str, float]:
        """Message name → current send rate (Hz), for messages being sent."""
        return {s.name: s.rate for s in self._streams.values() if s.rate > 0 and not s.name.startswith("_")}

    def advance(self, t: float) -> list[bytes]:
        """Step the vehicle clock to t (s) and return the packets due, replies first."""
        out, self._outbox = self._outbox, []
        heap, server = self._heap, self.param_server
        while True:
            due_stream = heap[0][0] if heap else float("inf")
            due_param = server.next_due if server.next_due is not None else float("inf")
            if min(due_stream, due_param) > t:
                break
            if due_param < due_stream:
                self.t = due_param
                out += [self._encode(m) for m in server.take_due(due_param)]
                continue
            due, _, generation, stream = heapq.heappop(heap)
            if generation != stream.generation:
                continue
            self.t = due
            stream.k += 1
            heapq.heappush(heap, (stream.start + stream.k / stream.rate, stream.order, generation, stream))
            if stream.name == _LOOP:
                self.autopilot.tick(due)
                self.logs.record_loop(due, self.autopilot, self.armed)
            elif stream.name == _GPS:
                self.autopilot.gps_tick(due)
                self.logs.record_gps(due, self.autopilot.fix)
            elif stream.name == _LOGS:
                out += [self._encode(m) for m in self.log_server.pump(due, self.armed)]
            else:
                out.append(self._encode(self.autopilot.build(stream.name, due)))
        self.t = max(self.t, t)
        return out

    def handle_bytes(self, data: bytes) -> None:
        """Parse bytes from the ground station and act on them; replies wait in the outbox for
        the next `advance` (or `take_replies`)."""
        for msg in self._parser.parse_buffer(data) or []:
            kind = msg.get_type()
            if kind == "BAD_DATA":
                if "signature" in getattr(msg, "reason", ""):
                    self.signature_rejected += 1
                continue
            if self.profile.mavlink1 and msg.get_msgbuf()[0] == MARKER_V2:
                continue  # APM 2.5 firmware has no MAVLink 2 parser
            self.received[kind] = self.received.get(kind, 0) + 1
            target = getattr(msg, "target_system", 0)
            if target not in (0, self.sysid):
                continue
            try:
                replies = self._handle(msg)
            except (ValueError, OverflowError):  # NaN / huge command parameters: ignore, count
                self.rejected += 1
                continue
            self._outbox += [self._encode(reply) for reply in replies]

    def set_signing_key(self, key: bytes | None, timestamp: int = 0) -> None:
        """Sign what the vehicle sends and refuse unsigned or badly signed packets (pymavlink's
        own check, as ArduPilot's), or, with None or an all-zero key and a zero timestamp, stop:
        SETUP_SIGNING's rule, as ArduPilot applies it (a zero key with a timestamp is a key)."""
        if key is None or (not any(key) and timestamp == 0):
            self.signing_key = None
            self._parser.signing.secret_key = None
            self._encoder.mav.signing.sign_outgoing = False
            return
        self.signing_key = key
        self._parser.signing.secret_key = key
        self._parser.signing.timestamp = max(self._parser.signing.timestamp, timestamp)
        Signing(key).sign_with(self._encoder)
        self._encoder.mavlink1 = self.profile.mavlink1  # an APM 2.5 cannot sign (MAVLink 1 only)

    def take_replies(self) -> list[bytes]:
        """Replies produced by `handle_bytes` since the last advance, removed from the outbox."""
        out, self._outbox = self._outbox, []
        return out

    async def run(self, address: str, on_open: Callable[[], None] | None = None) -> None:
        """Serve the link at `address` (udpout:, udpin:, tcp:, tcpin:, pty:) until cancelled;
        `on_open` is called once the link is open (OSError if it cannot be opened)."""
        endpoint = open_endpoint(address)
        if self.radio is not None:  # a bandwidth-limited telemetry radio in between (gcs.sim.radio)
            endpoint = self.radio.attach(endpoint)

        def on_data(data: bytes) -> None:
            self.handle_bytes(data)
            for packet in self.take_replies():
                endpoint.write(packet)

        await endpoint.open(on_data)
        if on_open is not None:
            on_open()
        loop = asyncio.get_running_loop()
        wall0, vehicle0 = loop.time(), self.t
        try:
            while True:
                now = vehicle0 + (loop.time() - wall0) * self.speed
                if (now - self.t) / self.speed > MAX_CATCH_UP:  # stalled (debugger, suspended laptop): slip
                    wall0, vehicle0 = loop.time(), self.t
                    now = self.t
                for packet in self.advance(now):
                    endpoint.write(packet)
                wait = (self._next_due() - now) / self.speed
                await asyncio.sleep(min(max(wait, 0.0005), 0.05))
        finally:
            endpoint.close()

    # --- scheduling ----------------------------------------------------------------------------

    def _next_due(self) -> float:
        due = self._heap[0][0] if self._heap else float("inf")
        if self.param_server.next_due is not None:
            due = min(due, self.param_server.next_due)
        return due

    def _set_rate(self, name: str, rate: float) -> None:
        """Change a stream's rate; an unchanged rate keeps its phase (GCSs repeat requests)."""
        stream = self._streams[name]
        if rate == stream.rate:
            return
        stream.rate, stream.start, stream.k = rate, self.t, 0
        stream.generation += 1
        if rate > 0:
            heapq.heappush(self._heap, (self.t, stream.order, stream.generation, stream))

    def _update_rates(self) -> None:
        """Recompute every message rate from defaults, group requests and per-message intervals."""
        p = self.profile
        for name in p.messages:
            if name in ("HEARTBEAT", "AUTOPILOT_VERSION"):
                continue
            rate = p.default_rates.get(name, 0.0)
            for group, members in p.groups.items():
                if name in members and group in self._group_rates:
                    rate = self._group_rates[group] * p.group_share.get(name, 1.0)
            rate = self._overrides.get(name, rate)
            if name == "GPS_RAW_INT":
                rate = min(rate, GPS_RATE_HZ)  # one message per receiver fix
            self._set_rate(name, rate)

    # --- commands --------------------------------------------------------------------------------

    def _encode(self, msg) -> bytes:
        return self._encoder.encode(msg)

    def _new_flight_log(self) -> FlightLog:
        """A flight's onboard log: the 3.1-3.2 TimeMS layouts on the APM 2.5, TimeUS otherwise."""
        return FlightLog(self.profile.log_time_ms, self.params.as_dict().items(), self.home)

    def _handle(self, msg) -> list:
        kind = msg.get_type()
        if kind.startswith("PARAM_"):
            banner = []
            if kind == "PARAM_REQUEST_LIST" and self.profile.banner:  # ArduPilot's send_banner()
                banner = [mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_INFO, self.profile.banner.encode())]
            return banner + self.param_server.handle(msg, self.t)
        if kind.startswith("LOG_") or kind == "HEARTBEAT":
            return self.log_server.handle(msg, self.t, self.armed)
        if kind == "REQUEST_DATA_STREAM":
            self._request_data_stream(msg)
        elif kind == "COMMAND_LONG":
            return self._command(msg)
        elif kind == "SETUP_SIGNING" and not self.profile.mavlink1:
            self.set_signing_key(bytes(msg.secret_key), msg.initial_timestamp)
        return []

    def _request_data_stream(self, msg) -> None:
        """ArduPilot semantics: start_stop 0 stops the group, else the group runs at the
        requested Hz (capped); MAV_DATA_STREAM_ALL sets every group. PX4 ignores this."""
        groups = self.profile.groups
        if not groups:
            return
        rate = 0.0 if msg.start_stop == 0 else min(float(msg.req_message_rate), self.profile.group_cap_hz)
        ids = groups if msg.req_stream_id == mavlink.MAV_DATA_STREAM_ALL else [msg.req_stream_id]
        for group in ids:
            if group in groups:
                self._group_rates[group] = rate
        self._update_rates()

    def _command(self, msg) -> list:
        cmd = msg.command
        p = self.profile
        result = mavlink.MAV_RESULT_UNSUPPORTED
        extra = []
        if cmd == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            self.autopilot.armed = msg.param1 >= 0.5
            result = mavlink.MAV_RESULT_ACCEPTED
            text = "Arming motors" if self.armed else "Disarming motors"
            extra = [self.autopilot.statustext(mavlink.MAV_SEVERITY_INFO, text)]
        elif cmd == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL and p.message_intervals:
            refusal = self._interval_refusal(int(msg.param1), msg.param2)
            if refusal is not None:
                result, extra = mavlink.MAV_RESULT_DENIED, refusal
            else:
                result = self._set_message_interval(int(msg.param1), msg.param2)
        elif cmd == mavlink.MAV_CMD_GET_MESSAGE_INTERVAL and p.message_intervals:
            name = _message_name(int(msg.param1))
            rate = self._streams[name].rate if name in self._streams else 0.0
            interval = int(round(1e6 / rate)) if rate > 0 else -1
            extra = [mavlink.MAVLink_message_interval_message(int(msg.param1), interval)]
            result = mavlink.MAV_RESULT_ACCEPTED
        elif (
            cmd in (mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES)
            and p.knows_autopilot_version
        ):
            msg_id = (
                int(msg.param1) if cmd == mavlink.MAV_CMD_REQUEST_MESSAGE else mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION
            )
            name = _message_name(msg_id)
            if name in p.messages:
                extra = [self.autopilot.build(name, self.t)]
                result = mavlink.MAV_RESULT_ACCEPTED
            else:
                result = mavlink.MAV_RESULT_FAILED
        ack = mavlink.MAVLink_command_ack_message(cmd, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())
        return [ack] + extra

    def _interval_refusal(self, msg_id: int, interval_us: float) -> list | None:
        """ArduPlane's STATUSTEXT for an interval faster than `interval_limits` allows (in 50-byte
        chunks of one id, as ArduPilot sends a long text over MAVLink 2), else None."""
        limit = self.interval_limits.get(_message_name(msg_id))
        if limit is None or interval_us <= 0 or 1e6 / interval_us <= limit + 1e-9:
            return None
        text = f"Requested rate for message ID {msg_id} too fast. Increase SCHED_LOOP_RATE".encode()
        self._text_id = self._text_id % 65535 + 1
        return [
            mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_INFO, text[i : i + 50], self._text_id, i // 50)
            for i in range(0, len(text), 50)
        ]

    def _set_message_interval(self, msg_id: int, interval_us: float) -> int:
        """param2: interval µs; 0 = back to the default, −1 = off. Rate capped per profile."""
        name = _message_name(msg_id)
        if name not in self.profile.messages or name in ("HEARTBEAT", "AUTOPILOT_VERSION"):
            return mavlink.MAV_RESULT_FAILED
        if interval_us == 0:
            self._overrides.pop(name, None)
        elif interval_us < 0:
            self._overrides[name] = 0.0
        else:
            self._overrides[name] = min(1e6 / interval_us, self.profile.interval_cap_hz)
        self._update_rates()
        return mavlink.MAV_RESULT_ACCEPTED


def _message_name(msg_id: int) -> str:
    cls = mavlink.mavlink_map.get(msg_id)
    return cls.msgname if cls is not None else ""


def open_endpoint(address: str):
    """The vehicle side of a link: a pseudo-terminal for pty:PATH, else a gcs.runtime transport."""
    if address.startswith("pty:"):
        return PtyTransport(address[len("pty:") :])

    return make_transport(address)
