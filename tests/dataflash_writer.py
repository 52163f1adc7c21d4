"""Writes DataFlash .bin logs for tests, and turns the real SITL hop log into the same flight in
the two generations of the format, because no ArduCopter 3.2 (TimeMS) log is in the shared data.

The binary format (as pymavlink's DFReader reads it): every record is 0xA3 0x95, a type byte and
the packed fields, little-endian. FMT records (type 128) define each type: its id, record length
(with the 3 header bytes), name (char[4]), format string (char[16]) and column names (char[64]).
Format characters c/C/e/E store value·100 as integers and L stores degrees·1e7; DFReader divides
them back. The 3.2 record layouts are those of ArduCopter 3.2's LogStructure / Log.cpp.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

from pymavlink.DFReader import DFReader_binary

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


#: ArduCopter 3.2 record layouts (name → format, columns).
OLD_FORMATS = {
    "IMU": ("Iffffff", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"),
    "IMU2": ("Iffffff", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"),
    "MAG": ("Ihhhhhhhhh", "TimeMS,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOfsX,MOfsY,MOfsZ"),
    "MAG2": ("Ihhhhhhhhh", "TimeMS,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOfsX,MOfsY,MOfsZ"),
    "GPS": ("BIHBcLLeeEefI", "Status,TimeMS,Week,NSats,HDop,Lat,Lng,RelAlt,Alt,Spd,GCrs,VZ,T"),
    "ATT": ("IccccCC", "TimeMS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw"),
    "AHR2": ("IccCfLL", "TimeMS,Roll,Pitch,Yaw,Alt,Lat,Lng"),
}
#: Today's layouts (TimeUS and an instance field), the columns the readers use.
NEW_FORMATS = {
    "IMU": ("QBffffff", "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"),
    "MAG": ("QBhhh", "TimeUS,I,MagX,MagY,MagZ"),
    "GPS": ("QBBIHBcLLeffff", "TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw"),
    "ATT": ("Qffffff", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw"),
    "AHR2": ("QccCfLL", "TimeUS,Roll,Pitch,Yaw,Alt,Lat,Lng"),
}


def _yaw_cdeg(yaw: float) -> int:
    return x100(yaw) % 36000


def _old_record(name: str, ms: int, r) -> tuple[str, tuple[object, ...]] | None:
    """One hop record as ArduCopter 3.2 logged it (TimeMS, the instance in the type name)."""
    instance = getattr(r, "I", 0)
    if name == "IMU" and instance < 2:
        return ("IMU", "IMU2")[instance], (ms, r.GyrX, r.GyrY, r.GyrZ, r.AccX, r.AccY, r.AccZ)
    if name == "MAG" and instance < 2:
        return ("MAG", "MAG2")[instance], (ms, r.MagX, r.MagY, r.MagZ, r.OfsX, r.OfsY, r.OfsZ, 0, 0, 0)
    if name == "GPS":
        gps = (r.Status, ms, r.GWk, r.NSats, x100(r.HDop), e7(r.Lat), e7(r.Lng), 0, x100(r.Alt))
        return "GPS", (*gps, x100(r.Spd), x100(r.GCrs), r.VZ, ms)
    if name == "ATT":
        angles = (x100(r.DesRoll), x100(r.Roll), x100(r.DesPitch), x100(r.Pitch), _yaw_cdeg(r.DesYaw))
        return "ATT", (ms, *angles, _yaw_cdeg(r.Yaw))
    if name == "AHR2":
        return "AHR2", (ms, x100(r.Roll), x100(r.Pitch), _yaw_cdeg(r.Yaw), r.Alt, e7(r.Lat), e7(r.Lng))
    return None


def _new_record(name: str, ms: int, r) -> tuple[str, tuple[object, ...]] | None:
    """The same record in today's layout, with the same quantised values and time (ms · 1000)."""
    old = _old_record(name, ms, r)
    if old is None:
        return None
    kind, v = old
    us, instance = ms * 1000, getattr(r, "I", 0)
    if name == "IMU":
        return "IMU", (us, instance, *v[1:])
    if name == "MAG":
        return "MAG", (us, instance, *v[1:4])
    if name == "GPS":
        status, _, week, nsats, hdop, lat, lng, _, alt, spd, gcrs, vz, _ = v
        return "GPS", (us, 0, status, 0, week, nsats, hdop, lat, lng, alt, spd / 100, gcrs / 100, vz, 0.0)
    if name == "ATT":
        return "ATT", (us, *(a / 100 for a in v[1:]))
    return kind, (us, *v[1:])


def hop_in_both_formats(path: str) -> tuple[DataflashWriter, DataflashWriter]:
    """The hop flight as an ArduCopter 3.2 log (TimeMS) and as a current one (TimeUS), the same
    instants (ms) and the same quantised values, so the estimates must be the same."""
    old, new = DataflashWriter(), DataflashWriter()
    for name, (fmt, columns) in OLD_FORMATS.items():
        old.define(name, fmt, columns)
    for name, (fmt, columns) in NEW_FORMATS.items():
        new.define(name, fmt, columns)
    log = DFReader_binary(path)
    while (r := log.recv_match(type=["IMU", "MAG", "GPS", "ATT", "AHR2"])) is not None:
        name, ms = r.get_type(), round(r.TimeUS / 1000)
        for writer, convert in ((old, _old_record), (new, _new_record)):
            record = convert(name, ms, r)
            if record is not None:
                writer.add(record[0], *record[1])
    return old, new
