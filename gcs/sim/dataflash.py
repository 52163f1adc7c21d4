"""DataFlash (.bin) logs as ArduPilot writes them: the simulator's onboard log of each flight,
and the test-side writer that rebuilds real logs in either generation of the format.

The binary format (as pymavlink's DFReader reads it): every record is 0xA3 0x95, a type byte and
the packed fields, little-endian. FMT records (type 128) define each type: its id, record length
(with the 3 header bytes), name (char[4]), format string (char[16]) and column names (char[64]).
Format characters c/C/e/E store value·100 as integers and L stores degrees·1e7; DFReader divides
them back. The TimeMS layouts are those of ArduCopter 3.1-3.2's LogStructure / Log.cpp (the APM
2.5 era), the TimeUS ones those of ArduCopter 3.3 and later (an instance field `I`).

`FlightLog` is what the simulated autopilot logs while it runs: PARM at boot, IMU at the loop
rate, ATT / AHR2 / SIM (truth) at 50 Hz, MAG at 10 Hz (ArduCopter's ten-hertz logging loop),
GPS at each fix.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable
from dataclasses import dataclass, field

from gcs.sim.motion import Truth
from gcs.sim.sensors import GpsFix, Home, ImuReading

HEADER = b"\xa3\x95"
FMT_TYPE = 128
#: DataFlash format character → struct code.
STRUCT_CODES = {
    "b": "b", "B": "B", "h": "h", "H": "H", "i": "i", "I": "I", "f": "f", "d": "d", "n": "4s", "N": "16s",
    "Z": "64s", "c": "h", "C": "H", "e": "i", "E": "I", "L": "i", "M": "B", "q": "q", "Q": "Q",
}  # fmt: skip


@dataclass
class DataflashWriter:
    """Records in file order; `ends[k]` is the byte offset just after record k (name, offset)."""

    chunks: list[bytes] = field(default_factory=list)
    types: dict[str, tuple[int, struct.Struct]] = field(default_factory=dict)
    ends: list[tuple[str, int]] = field(default_factory=list)
    size: int = 0

    def __post_init__(self) -> None:
        self.define("FMT", "BBnNZ", "Type,Length,Name,Format,Columns", FMT_TYPE)

    def define(self, name: str, fmt: str, columns: str, type_id: int | None = None) -> None:
        type_id = FMT_TYPE + len(self.types) if type_id is None else type_id
        packer = struct.Struct("<" + "".join(STRUCT_CODES[c] for c in fmt))
        self.types[name] = (type_id, packer)
        self.add("FMT", type_id, 3 + packer.size, name.encode(), fmt.encode(), columns.encode())

    def add(self, name: str, *values: object) -> None:
        type_id, packer = self.types[name]
        chunk = HEADER + bytes([type_id]) + packer.pack(*values)
        self.chunks.append(chunk)
        self.size += len(chunk)
        self.ends.append((name, self.size))

    def bytes(self) -> bytes:
        return b"".join(self.chunks)


def x100(value: float) -> int:
    """A c/C/e/E field's stored integer."""
    return round(value * 100)


def e7(degrees: float) -> int:
    """An L field's stored integer."""
    return round(degrees * 1e7)


def yaw_cdeg(yaw_deg: float) -> int:
    """A C yaw field (centidegrees, 0..35999)."""
    return x100(yaw_deg) % 36000


#: ArduCopter 3.1-3.2 record layouts (name → format, columns).
OLD_FORMATS = {
    "PARM": ("Nf", "Name,Value"),
    "IMU": ("Iffffff", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"),
    "IMU2": ("Iffffff", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"),
    "MAG": ("Ihhhhhhhhh", "TimeMS,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOfsX,MOfsY,MOfsZ"),
    "MAG2": ("Ihhhhhhhhh", "TimeMS,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOfsX,MOfsY,MOfsZ"),
    "GPS": ("BIHBcLLeeEefI", "Status,TimeMS,Week,NSats,HDop,Lat,Lng,RelAlt,Alt,Spd,GCrs,VZ,T"),
    "ATT": ("IccccCC", "TimeMS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw"),
    "AHR2": ("IccCfLL", "TimeMS,Roll,Pitch,Yaw,Alt,Lat,Lng"),
    "SIM": ("IccCfLL", "TimeMS,Roll,Pitch,Yaw,Alt,Lat,Lng"),
}
#: Today's layouts (TimeUS and an instance field), the columns the readers use.
NEW_FORMATS = {
    "PARM": ("QNf", "TimeUS,Name,Value"),
    "IMU": ("QBffffff", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"),
    "MAG": ("QBhhh", "TimeUS,I,MagX,MagY,MagZ"),
    "GPS": ("QBBIHBcLLeffff", "TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw"),
    "ATT": ("Qffffff", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw"),
    "AHR2": ("QccCfLL", "TimeUS,Roll,Pitch,Yaw,Alt,Lat,Lng"),
    "SIM": ("QccCfLLffff", "TimeUS,Roll,Pitch,Yaw,Alt,Lat,Lng,Q1,Q2,Q3,Q4"),
}

#: Rates of the slower records (Hz); IMU is logged at every loop.
ATTITUDE_LOG_HZ = 50.0
MAG_LOG_HZ = 10.0
GPS_FIX_3D = 3
#: The simulated receiver's GPS time of week at boot (ms), and a week in ms: a 3.2 GPS record's
#: TimeMS is this clock, not the boot time.
GPS_WEEK_MS_AT_BOOT = 130_040_903
GPS_WEEK_MS = 604_800_000
#: Loop instants are k / loop_hz in floating point: a record due at that instant is taken there.
TIME_SLACK = 1e-6
#: A log stops growing here (a full card): 64 MiB, over an hour of 400 Hz logging.
MAX_LOG_BYTES = 64 << 20


def _mgauss(gauss: float) -> int:
    return max(-32768, min(32767, round(gauss * 1000.0)))


def _degrees(angles: Iterable[float]) -> list[float]:
    return [math.degrees(a) for a in angles]


class FlightLog:
    """One flight's onboard log, written record by record as the simulated autopilot runs.

    `time_ms`: the ArduCopter 3.1-3.2 layouts (TimeMS, IMU2/MAG2 types), else TimeUS ones.
    Only instance 0 of each sensor is logged (the one the onboard filters use)."""

    def __init__(self, time_ms: bool, params: Iterable[tuple[str, float]], home: Home) -> None:
        self.time_ms, self.home = time_ms, home
        formats = DataflashWriter()
        for name, (fmt, columns) in (OLD_FORMATS if time_ms else NEW_FORMATS).items():
            formats.define(name, fmt, columns)
        #: record name → (header, packer); records go straight into one buffer (hours of 400 Hz IMU)
        self._types = {name: (HEADER + bytes([type_id]), packer) for name, (type_id, packer) in formats.types.items()}
        self.data = bytearray(formats.bytes())
        self.full = False
        for name, value in params:
            self._add("PARM", 0.0, name.encode(), float(value))
        self._next_attitude = 0.0
        self._next_mag = 0.0

    @property
    def size(self) -> int:
        return len(self.data)

    def bytes(self) -> bytes:
        return bytes(self.data)

    def _add(self, name: str, t: float, *values: object) -> None:
        """A record stamped with vehicle time t (s), in the layout's clock; PARM is untimed in 3.2.
        At MAX_LOG_BYTES the log is full and stops growing, as a full card does."""
        if len(self.data) >= MAX_LOG_BYTES:
            self.full = True
            return
        header, packer = self._types[name]
        self.data += header
        if name == "PARM" and self.time_ms:
            self.data += packer.pack(*values)
        elif self.time_ms:
            self.data += packer.pack(round(t * 1e3), *values)
        else:
            self.data += packer.pack(round(t * 1e6), *values)

    def loop(self, t: float, imu: ImuReading, attitude: tuple[float, float, float], ahrs2, truth: Truth) -> None:
        """One autopilot loop: IMU always; ATT, AHR2 (when the board has a second filter) and
        SIM at ATTITUDE_LOG_HZ; MAG at MAG_LOG_HZ. Angles in rad, ahrs2: (euler, GpsFix) or None."""
        instance = () if self.time_ms else (0,)
        self._add("IMU", t, *instance, *imu.gyro, *imu.accel)
        if t + TIME_SLACK >= self._next_mag:
            self._next_mag = max(self._next_mag + 1.0 / MAG_LOG_HZ, t)
            mag = [_mgauss(m) for m in imu.mag]
            self._add("MAG", t, *instance, *mag, *([0] * 6 if self.time_ms else ()))
        if t + TIME_SLACK < self._next_attitude:
            return
        self._next_attitude = max(self._next_attitude + 1.0 / ATTITUDE_LOG_HZ, t)
        roll, pitch, yaw = _degrees(attitude)
        if self.time_ms:
            self._add("ATT", t, x100(roll), x100(roll), x100(pitch), x100(pitch), yaw_cdeg(yaw), yaw_cdeg(yaw))
        else:
            self._add("ATT", t, roll, roll, pitch, pitch, yaw % 360.0, yaw % 360.0)
        if ahrs2 is not None:
            euler, fix = ahrs2
            r2, p2, y2 = _degrees(euler)
            self._add("AHR2", t, x100(r2), x100(p2), yaw_cdeg(y2), fix.alt, e7(fix.lat), e7(fix.lon))
        lat, lon = self.home.lat_lon(float(truth.pos[0]), float(truth.pos[1]))
        tr, tp, ty = _degrees(truth.euler)
        sim = (x100(tr), x100(tp), yaw_cdeg(ty), self.home.alt - float(truth.pos[2]), e7(lat), e7(lon))
        self._add("SIM", t, *sim, *(() if self.time_ms else map(float, truth.q)))

    def _add_untimed(self, name: str, *values: object) -> None:
        """A record whose time field is not first (the 3.2 GPS): the values as given."""
        if len(self.data) < MAX_LOG_BYTES:
            header, packer = self._types[name]
            self.data += header + packer.pack(*values)

    def gps(self, t: float, fix: GpsFix) -> None:
        """One receiver fix (3D, 12 satellites, HDOP 0.9, as the GPS_RAW_INT the sim sends)."""
        course = math.degrees(fix.course) % 360.0
        if self.time_ms:  # TimeMS is the receiver's GPS time of week (week 0: no date), T the boot time
            ms = round(t * 1e3)
            week_ms = (GPS_WEEK_MS_AT_BOOT + ms) % GPS_WEEK_MS
            self._add_untimed(
                "GPS", GPS_FIX_3D, week_ms, 0, 12, x100(0.9), e7(fix.lat), e7(fix.lon), x100(fix.alt - self.home.alt),
                x100(fix.alt), x100(fix.ground_speed), x100(course), fix.vel_ned[2], ms,
            )  # fmt: skip
        else:
            self._add(
                "GPS", t, 0, GPS_FIX_3D, 0, 0, 12, x100(0.9), e7(fix.lat), e7(fix.lon), x100(fix.alt),
                fix.ground_speed, course, fix.vel_ned[2], 0.0,
            )  # fmt: skip
