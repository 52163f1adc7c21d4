"""Plain-text attitude streams (no MAVLink) turned into the MAVLink a ground station understands.

Seed 000's firmware prints one line per loop, `pitch,yaw,roll\\r\\n` in degrees at 57600 baud
(seed-000 §10.1) and nothing else. `AsciiAttitudeDecoder` reads such lines from any byte stream
and hands back, per good line, an ATTITUDE message (the firmware's own estimate: `onboard`)
stamped with the host clock since the stream began (the lines carry no time), plus a HEARTBEAT
once a second so the link shows the device as connected. The messages are packed, so the
recorder writes them to the session's tlog like any received packet and a replay reads them back.
A line that does not parse (wrong field count, not a number, beyond ±720°, longer than
`MAX_LINE`) is counted in `counters.malformed` and skipped.
"""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass

from gcs.mavlink.dialect import Encoder, MAVLinkMessage, mavlink
from gcs.mavlink.framing import Frame, FramingCounters

ANGLES = ("roll", "pitch", "yaw")
UNITS = ("deg", "rad")
#: Longer than any angle line; past this without a newline the bytes are a malformed line.
MAX_LINE = 256


@dataclass(frozen=True, slots=True)
class AsciiFormat:
    """Column order (`roll`, `pitch`, `yaw`, or `-` for a column to ignore), unit and separator."""

    fields: tuple[str, ...] = ("pitch", "yaw", "roll")
    unit: str = "deg"
    separator: str = ","

    def __post_init__(self) -> None:
        named = [f for f in self.fields if f != "-"]
        if sorted(named) != sorted(ANGLES):
            raise ValueError(f"ASCII fields {','.join(self.fields)!r}: need roll, pitch and yaw once each (- skips)")
        if self.unit not in UNITS:
            raise ValueError(f"ASCII unit {self.unit!r}: use deg or rad")

    @classmethod
    def parse(cls, fields: str, unit: str = "deg") -> AsciiFormat:
        """From `pitch,yaw,roll`-style text (the --ascii-fields option)."""
        return cls(tuple(f.strip() for f in fields.split(",")), unit)

    def line(self, roll: float, pitch: float, yaw: float) -> str:
        """The line a device in this format prints for an attitude in radians (2 decimals, as
        Arduino's Serial.print(float) gives)."""
        values = {"roll": roll, "pitch": pitch, "yaw": yaw}
        scale = math.degrees if self.unit == "deg" else float
        return self.separator.join("0" if f == "-" else f"{scale(values[f]):.2f}" for f in self.fields) + "\r\n"


#: Seed 000's firmware: pitch, yaw, roll in degrees.
SEED000 = AsciiFormat()


class AsciiAttitudeDecoder:
    """Incremental: feed() bytes in any chunking, get ATTITUDE (and HEARTBEAT) messages back."""

    def __init__(self, fmt: AsciiFormat = SEED000, clock: Callable[[], float] = time.monotonic) -> None:
        self.format = fmt
        self.clock = clock
        self.counters = FramingCounters()  # packets: good lines; malformed: bad lines
        self._buf = bytearray()
        self._skipping = False
        self._encoder = Encoder(1, 1)
        self._t0: float | None = None
        self._next_heartbeat = 0.0
        self._scale = math.radians if fmt.unit == "deg" else float

    def new_stream(self) -> None:
        """The bytes that follow come from a new connection: the old one's unfinished line is
        dropped (counted as skipped), not joined to the new bytes."""
        self.counters.bytes_skipped += len(self._buf)
        del self._buf[:]
        self._skipping = False

    def feed(self, data: bytes, final: bool = False) -> list[MAVLinkMessage]:
        buf = self._buf
        buf += data
        out: list[MAVLinkMessage] = []
        while True:
            end = buf.find(b"\n")
            if end < 0:
                if len(buf) > MAX_LINE:  # no line ending in sight: garbage, up to the next ending
                    if not self._skipping:
                        self._bad(0)
                    self.counters.bytes_skipped += len(buf)
                    self._skipping = True
                    del buf[:]
                break
            line = bytes(buf[:end])
            del buf[: end + 1]
            if self._skipping:  # the end of an overlong line, already counted
                self._skipping = False
                self.counters.bytes_skipped += len(line) + 1
                continue
            out += self._line(line)
        if final and buf:  # a datagram ends its last line
            line = bytes(buf)
            del buf[:]
            out += self._line(line)
        return out

    def frames(self, data: bytes, final: bool = False) -> list[Frame]:
        """What `feed` gives, as packets (the link's framing's output)."""
        return [
            (bytes(m.get_msgbuf()), m.get_type(), m.get_srcSystem(), m.get_srcComponent())
            for m in self.feed(data, final)
        ]

    def _line(self, raw: bytes) -> list[MAVLinkMessage]:
        text = raw.strip()
        if not text:
            return []
        angles = self._angles(text)
        if angles is None:
            self._bad(len(raw) + 1)
            return []
        now = self.clock()
        if self._t0 is None:
            self._t0 = now
        t = now - self._t0
        out = []
        if t >= self._next_heartbeat:
            self._next_heartbeat = t + 1.0
            out.append(
                self._pack(
                    mavlink.MAVLink_heartbeat_message(
                        mavlink.MAV_TYPE_GENERIC, mavlink.MAV_AUTOPILOT_GENERIC, 0, 0, mavlink.MAV_STATE_ACTIVE, 3
                    )
                )
            )
        out.append(self._pack(mavlink.MAVLink_attitude_message(int(t * 1e3), *angles, 0.0, 0.0, 0.0)))
        self.counters.packets += 1
        return out

    def _angles(self, text: bytes) -> tuple[float, float, float] | None:
        try:
            cells = text.decode("ascii").split(self.format.separator)
        except UnicodeDecodeError:
            return None
        if len(cells) != len(self.format.fields):
            return None
        values = {}
        for name, cell in zip(self.format.fields, cells):
            if name == "-":
                continue
            try:
                value = float(cell)
            except ValueError:
                return None
            angle = self._scale(value)
            if not abs(angle) <= 2 * math.tau:  # NaN, infinite, or no attitude angle at all
                return None
            values[name] = _float32(angle)
        return values["roll"], values["pitch"], values["yaw"]

    def _pack(self, msg: MAVLinkMessage) -> MAVLinkMessage:
        self._encoder.encode(msg)  # packs it: the message carries its wire bytes and header
        return msg

    def _bad(self, size: int) -> None:
        self.counters.malformed += 1
        self.counters.bytes_skipped += size


def _float32(value: float) -> float:
    """The value as ATTITUDE's float field carries it, so the live message equals its replay."""
    return float(struct.unpack("<f", struct.pack("<f", value))[0])
