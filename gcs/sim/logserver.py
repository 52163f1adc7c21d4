"""The simulated vehicle's onboard logs and the MAVLink log protocol that serves them, with
ArduPilot's rules (AP_Logger_MAVLinkLogTransfer):

- LOG_REQUEST_LIST → one LOG_ENTRY (id, num_logs, last_log_num, time_utc, size) per send loop,
  ids 1..N; with no log a single entry with id 0;
- LOG_REQUEST_DATA (id, ofs, count) → LOG_DATA of 90 bytes each from ofs until count bytes or the
  end of the log (a short chunk ends it), `sends_per_loop` per send loop: 40 in SITL, 10 on a
  serial port with flow control, 1 on one without (a 3DR radio on an APM), 250 on USB. While a
  transfer runs, further requests on the link are silently ignored (MAVProxy streams them);
- LOG_REQUEST_END stops; LOG_ERASE erases; nothing is served while armed ("Disarm for log
  download") or when the ground station's heartbeat is older than 3 s.

Logs: the finished ones (flights flown before, gcs.sim.recording.fly_flight_logs) and the current flight, written
from boot; a list request closes the current one (its size must not change under a download)
and the next arming starts a new one. `log_dir`: each finished log is also written there as
ArduPilot names them (00000001.BIN), the bytes a download must reproduce.
"""

from __future__ import annotations

from collections.abc import Callable
from enum import Enum
from pathlib import Path

import numpy as np

from gcs.mavlink.dialect import mavlink
from gcs.sim.autopilot import Autopilot
from gcs.sim.dataflash import FlightLog
from gcs.sim.sensors import GpsFix

LOG_DATA_LEN = 90
#: Rate of the GCS send loop where the logger sends (ArduCopter 3.2 gcs_send at 50 Hz).
SEND_LOOP_HZ = 50.0
#: LOG_DATA per send loop in SITL ("assume USB speeds").
SITL_SENDS_PER_LOOP = 40
#: No log traffic when the ground station's heartbeat is older than this (s).
HEARTBEAT_GRACE = 3.0
#: LOG_ENTRY.time_utc of the simulated logs (the simulator's fixed date, 2026-01-01).
LOG_TIME_UTC = 1_767_225_600


class Activity(Enum):
    IDLE = 0
    LISTING = 1
    SENDING = 2


class LogStore:
    """The finished logs (bytes, log id = index + 1) and the current flight's log, fed by the
    autopilot loop and the GPS; `new_log` starts a flight's log (PARM records first)."""

    def __init__(self, new_log: Callable[[], FlightLog], log_dir: Path | None = None) -> None:
        self.new_log, self.log_dir = new_log, log_dir
        self.finished: list[bytes] = []
        self.current: FlightLog | None = new_log()

    def record_loop(self, t: float, autopilot: Autopilot, armed: bool) -> None:
        if self.current is None:
            if not armed:
                return
            self.current = self.new_log()  # arming starts a new log
        ap = autopilot
        assert ap.imu_reading is not None, "the loop has sampled the IMU"
        ahrs2 = (ap.secondary.euler(), ap.fix) if ap.secondary is not None and ap.fix is not None else None
        self.current.loop(t, ap.imu_reading, ap.primary.euler(), ahrs2, ap.truth(t))

    def record_gps(self, t: float, fix: GpsFix | None) -> None:
        if self.current is not None and fix is not None:
            self.current.gps(t, fix)

    def close_current(self) -> None:
        if self.current is None:
            return
        data, self.current = self.current.bytes(), None
        self.add(data)

    def add(self, data: bytes) -> None:
        """A finished log, the next id; also written to log_dir (renamed whole when written)."""
        self.finished.append(data)
        if self.log_dir is not None:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            target = self.log_dir / f"{len(self.finished):08d}.BIN"
            partial = target.with_name(target.name + ".partial")
            partial.write_bytes(data)
            partial.replace(target)


class LogServer:
    """The vehicle side of the log protocol. `handle(msg, now, armed)` → immediate replies;
    `pump(now, armed)` → what one send loop sends. `drop`: fraction of LOG_DATA lost on the way
    (seeded), for tests of the ground station's re-requests. `has_room`: the link's
    HAVE_PAYLOAD_SPACE (a radio's buffer), asked before each packet."""

    def __init__(self, store: LogStore, rng: np.random.Generator, sends_per_loop: int = SITL_SENDS_PER_LOOP) -> None:
        self.store, self.rng = store, rng
        self.sends_per_loop = sends_per_loop
        self.drop = 0.0
        self.has_room: Callable[[], bool] = lambda: True
        self.activity = Activity.IDLE
        self.last_gcs_heartbeat: float | None = None
        self.warned_armed = False
        self.sent = 0  # LOG_DATA sent (dropped ones included)
        self.dropped = 0
        self._next_entry = self._last_entry = 0
        self._log_id = 0
        self._data: bytes = b""
        self._offset = self._remaining = 0

    def _num_logs(self) -> int:
        return len(self.store.finished)

    def handle(self, msg, now: float, armed: bool) -> list:
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            if msg.type == mavlink.MAV_TYPE_GCS:
                self.last_gcs_heartbeat = now
            return []
        if armed:
            if self.warned_armed:
                return []
            self.warned_armed = True
            return [mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_ERROR, b"Disarm for log download")]
        self.warned_armed = False
        if kind == "LOG_REQUEST_LIST":
            if self.activity != Activity.IDLE:
                return [mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_INFO, b"Log download in progress")]
            self.store.close_current()
            n = self._num_logs()
            self._next_entry = 0 if n == 0 else max(1, msg.start)
            self._last_entry = 0 if n == 0 else min(msg.end, n)
            self.activity = Activity.LISTING
        elif kind == "LOG_REQUEST_DATA":
            self._request_data(msg.id, msg.ofs, msg.count)
        elif kind == "LOG_REQUEST_END":
            self.activity = Activity.IDLE
        elif kind == "LOG_ERASE":
            self.store.finished.clear()
        return []

    def _request_data(self, log_id: int, ofs: int, count: int) -> None:
        if self.activity != Activity.IDLE:
            return  # a transfer is running: ignored silently (same link)
        if not 1 <= log_id <= self._num_logs():
            return
        self._log_id, self._data = log_id, self.store.finished[log_id - 1]
        self._offset = ofs
        self._remaining = min(max(len(self._data) - ofs, 0), count)
        self.activity = Activity.SENDING

    def pump(self, now: float, armed: bool) -> list:
        """One send loop's LOG_ENTRY or LOG_DATA packets (the dropped ones left out)."""
        if self.activity == Activity.IDLE or armed:
            return []
        if self.last_gcs_heartbeat is None or now - self.last_gcs_heartbeat > HEARTBEAT_GRACE:
            return []  # give a heartbeat a chance
        if self.activity == Activity.LISTING:
            return self._entry() if self.has_room() else []
        out = []
        for _ in range(self.sends_per_loop):
            if self.activity != Activity.SENDING or not self.has_room():
                break
            packet = self._chunk()
            self.sent += 1
            if self.drop and self.rng.random() < self.drop:
                self.dropped += 1
            else:
                out.append(packet)
        return out

    def _entry(self) -> list:
        log_id = self._next_entry
        size = len(self.store.finished[log_id - 1]) if log_id else 0
        entry = mavlink.MAVLink_log_entry_message(
            log_id, self._num_logs(), self._last_entry, LOG_TIME_UTC if log_id else 0, size
        )
        if self._next_entry >= self._last_entry:
            self.activity = Activity.IDLE
        else:
            self._next_entry += 1
        return [entry]

    def _chunk(self):
        n = min(self._remaining, LOG_DATA_LEN)
        data = self._data[self._offset : self._offset + n]
        packet = mavlink.MAVLink_log_data_message(self._log_id, self._offset, n, data.ljust(LOG_DATA_LEN, b"\0"))
        self._offset += n
        self._remaining -= n
        if n < LOG_DATA_LEN or self._remaining == 0:
            self.activity = Activity.IDLE
        return packet
