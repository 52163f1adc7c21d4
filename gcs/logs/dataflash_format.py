"""The DataFlash container (ArduPilot .bin) read straight into NumPy: the record types asked for
as structured arrays, in file order, and where the file is damaged.

A 98 s SITL flight is 177,000 records of 190 types, of which the estimators want a few thousand.
pymavlink's DFReader indexes every record and then builds a Python object per wanted record
whose fields are looked up by name at each access; here one compiled walk over the record
headers (`record_index`) finds them all, the few FMT records are read in Python, and the records
of each wanted type are gathered with one NumPy index and viewed through a dtype built from the
type's format string. The values are DFReader's, bit for bit (tests/test_dataflash_columns.py).

Format (ArduPilot's LogStructure.h; pymavlink's DFReader): every record is 0xA3 0x95, a type byte
and the packed little-endian fields. FMT records (type 128, 89 bytes) define a type: its id,
record length (header included), name (char[4]), format characters (char[16]) and column names
(char[64], comma-separated). The characters c/C/e/E store value·100 and L degrees·1e7 as
integers; `scaled` divides them back as DFReader does (by 100 and 1e7: it divides rather than
multiplies, for accuracy). FMTU / MULT records only name units for display: DFReader applies no
multiplier from them, and neither does this reader.

Damage: a record header that is not 0xA3 0x95, or whose type no FMT defined, is skipped byte by
byte up to the next header of a defined type (DFReader's resynchronisation, which stops at an
undefined type instead); a file cut inside a record is read up to that record; an FMT that cannot
be right (length under 3, a format whose size is not its length, unknown format characters,
columns not one per character, a column the caller needs missing or of the wrong kind) is refused
and its records are not decoded; a later FMT that defines a type (FMT itself included) otherwise
than its first one is refused and the first holds.
As DFReader does, bytes that are no record within the last 528 bytes of a file are taken for the
padding a block-based log ends with, not for damage. `damage` names each place and what was done.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from gcs.core.estimators.jit import kernel
from gcs.logs.logfile import InputError
from gcs.logs.offsets import appended

HEAD1, HEAD2 = 0xA3, 0x95
FMT_TYPE = 0x80
FMT_LENGTH = 89
#: The FMT record's own layout (type, length, name, format, columns).
FMT_DTYPE = np.dtype([("Type", "u1"), ("Length", "u1"), ("Name", "S4"), ("Format", "S16"), ("Columns", "S64")])
#: The FMT record that defines FMT itself, as ArduPilot writes it first (type, length, name, format).
FMT_BODY = bytes([FMT_TYPE, FMT_LENGTH]) + b"FMT\0" + b"BBnNZ".ljust(16, b"\0")
#: DataFlash format character → NumPy type (DFReader's FORMAT_TO_STRUCT: 'M' is int8, 'a' int16[32]).
TYPES = {
    "a": ("<i2", (32,)), "b": "i1", "B": "u1", "g": "<f2", "h": "<i2", "H": "<u2", "i": "<i4", "I": "<u4",
    "f": "<f4", "d": "<f8", "n": "S4", "N": "S16", "Z": "S64", "c": "<i2", "C": "<u2", "e": "<i4",
    "E": "<u4", "L": "<i4", "M": "i1", "q": "<i8", "Q": "<u8",
}  # fmt: skip
#: Text format characters (char[4], char[16], char[64]) and the int16[32] array.
TEXT = "nNZa"
#: Columns that are text in every record type that has them (PARM's, MSG's).
TEXT_COLUMNS = ("Name", "Message")
#: Scaled format characters → the divisor DFReader applies (1 / its multiplier: 0.01, 1e-7).
DIVISORS = {"c": 1 / 0.01, "C": 1 / 0.01, "e": 1 / 0.01, "E": 1 / 0.01, "L": 1 / 1.0e-7}
#: Bytes that are no record this close to the end are a block log's padding (DFReader's rule).
TAIL_PADDING = 528
#: Bytes per record to size the offsets for at first (40 in ArduCopter logs; a record is at
#: least 3, so room for every possible one would take 2.7 times the file's size).
GUESSED_RECORD_SIZE = 32
#: record_index's stops
CLEAN, CUT = 0, 1
#: record_index's damage kinds
BAD_HEADER, UNDEFINED_TYPE = 0, 1


@kernel
def record_index(
    buf: npt.NDArray[np.uint8], lengths: npt.NDArray[np.int64]
) -> tuple[npt.NDArray[np.int64], int, int, int, int, int]:
    """Offsets of the records, walking their headers with the lengths FMT records give (the
    first definition of a type counts; `lengths` holds FMT's own on entry and every defined
    type's on return), and (stop, why, first_bad, bad_kind, bad_bytes): where and why the walk
    stopped (CLEAN at the end, CUT at a record or header that the file ends inside), the first
    skipped byte that is damage (-1: none), what it was, and how many bytes were skipped."""
    end = len(buf)
    offsets = np.empty(end // GUESSED_RECORD_SIZE + 16, dtype=np.int64)  # grown when records are shorter
    n, pos, first_bad, bad_kind, bad_bytes = 0, 0, -1, BAD_HEADER, 0
    while pos + 3 <= end:
        kind = buf[pos + 2]
        defined = buf[pos] == HEAD1 and buf[pos + 1] == HEAD2 and lengths[kind] >= 3
        if not defined:
            if first_bad < 0 and (end - pos >= TAIL_PADDING or end < TAIL_PADDING):
                first_bad = pos
                bad_kind = UNDEFINED_TYPE if buf[pos] == HEAD1 and buf[pos + 1] == HEAD2 else BAD_HEADER
            bad_bytes += 1
            pos += 1
            continue
        size = lengths[kind]
        if pos + size > end:
            return offsets[:n], pos, CUT, first_bad, bad_kind, bad_bytes
        if kind == FMT_TYPE:
            defines, length = buf[pos + 3], buf[pos + 4]
            if lengths[defines] == 0 and defines != FMT_TYPE:
                lengths[defines] = length if length >= 3 else -1  # -1: refused, never walked over
        offsets = appended(offsets, n, pos)
        n += 1
        pos += size
    if pos < end and buf[pos] == HEAD1 and (pos + 1 == end or buf[pos + 1] == HEAD2):
        return offsets[:n], pos, CUT, first_bad, bad_kind, bad_bytes  # cut inside a record's header
    return offsets[:n], pos, CLEAN, first_bad, bad_kind, bad_bytes


@dataclass(frozen=True)
class Damage:
    """Where the file is damaged, what was found there and what the reader did about it."""

    offset: int
    cause: str


@dataclass(frozen=True)
class RecordFormat:
    """One FMT record: the type's id, name, format characters, columns and the row dtype."""

    type_id: int
    name: str
    format: str
    columns: tuple[str, ...]
    dtype: np.dtype[np.void]


@dataclass
class DataflashContents:
    """What `read_dataflash` found. `records[name]`: every record of that type in file order
    (structured, raw stored values: see `scaled`), `positions[name]` their indexes among all the
    file's records (so types merge in file order); `offsets` every record's byte offset, by that
    index (a place to name to the user: an index is no offset in the file); `formats` every type
    defined; `end` the byte offset where reading stopped."""

    records: dict[str, npt.NDArray[np.void]] = field(default_factory=dict)
    positions: dict[str, npt.NDArray[np.int64]] = field(default_factory=dict)
    offsets: npt.NDArray[np.int64] = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    formats: dict[str, RecordFormat] = field(default_factory=dict)
    damage: list[Damage] = field(default_factory=list)
    end: int = 0


def field_text(raw: bytes) -> str:
    """A char[n] field as DFReader gives it: UTF-8 (else Latin-1) up to the first NUL."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("ISO-8859-1")
    return text.split("\0", 1)[0]


def record_format(row: np.void, required: Collection[str] = ()) -> RecordFormat:
    """An FMT record → the type's format; ValueError saying why it cannot be right or lacks a
    column of `required` (numeric, but text for TEXT_COLUMNS)."""
    type_id, length = int(row["Type"]), int(row["Length"])
    name, chars = field_text(bytes(row["Name"])), field_text(bytes(row["Format"]))
    columns = tuple(field_text(bytes(row["Columns"])).split(",")) if row["Columns"] else ()
    unknown = sorted(set(chars) - set(TYPES))
    if unknown:
        raise ValueError(f"{name} has unknown format characters {''.join(unknown)!r}")
    if len(columns) != len(chars) or len(set(columns)) != len(columns):
        raise ValueError(f"{name} has {len(columns)} column names for {len(chars)} format characters")
    kinds = dict(zip(columns, chars, strict=True))
    missing = [c for c in required if c not in kinds or (kinds[c] in TEXT) != (c in TEXT_COLUMNS)]
    if missing:
        raise ValueError(f"{name} has no {', '.join(missing)} of the kind it must be (text or number)")
    dtype = np.dtype([(c, TYPES[f]) for c, f in kinds.items()])
    if dtype.itemsize + 3 != length:
        raise ValueError(f"{name} records of {length} bytes where the format {chars!r} has {dtype.itemsize + 3}")
    return RecordFormat(type_id, name, chars, columns, dtype)


def scaled(rows: npt.NDArray[np.void], fmt: RecordFormat, column: str) -> npt.NDArray[np.float64]:
    """A numeric column as float64 in the units DFReader gives (c/C/e/E / 100, L / 1e7)."""
    values = np.asarray(rows[column]).astype(np.float64)
    divisor = DIVISORS.get(fmt.format[fmt.columns.index(column)])
    return values if divisor is None else values / divisor


def _windows(
    buf: npt.NDArray[np.uint8], offsets: npt.NDArray[np.int64], dtype: np.dtype[np.void]
) -> npt.NDArray[np.void]:
    """The records at offsets viewed through dtype (one copy of each record's body)."""
    if dtype.itemsize == 0 or len(buf) < dtype.itemsize + 3:  # a record of no fields is its header alone
        return np.zeros(len(offsets) if dtype.itemsize == 0 else 0, dtype=dtype)
    windows = np.lib.stride_tricks.as_strided(buf, (len(buf) - dtype.itemsize + 1, dtype.itemsize), (1, 1))
    return windows[offsets + 3].view(dtype).reshape(-1)


def read_dataflash(
    path: str, wanted: Mapping[str, Collection[str]], buf: npt.NDArray[np.uint8] | None = None
) -> DataflashContents:
    """The record types named in `wanted` (each with the columns it must have, else its FMT is
    refused: see record_format) and the damage of the .bin at path (or of `buf`, the records of
    a text log: gcs.logs.dataflash_text); InputError when it cannot be read or holds no DataFlash
    record."""
    try:
        buf = np.fromfile(path, dtype=np.uint8) if buf is None else buf
    except OSError as exc:
        raise InputError(f"{path}: offset 0: cannot read ({exc.strerror})") from None
    lengths = np.zeros(256, dtype=np.int64)
    lengths[FMT_TYPE] = FMT_LENGTH
    offsets, end, why, first_bad, bad_kind, bad_bytes = record_index(buf, lengths)
    contents = DataflashContents(offsets=offsets, end=end)
    if not len(offsets):
        raise InputError(f"{path}: offset 0: not a DataFlash log (no record header 0xA3 0x95 with a defined type)")
    kinds = buf[offsets + 2]
    if first_bad >= 0:
        what = (
            f"record of type {int(buf[first_bad + 2])}, which no FMT defined"
            if bad_kind == UNDEFINED_TYPE
            else f"bad record header 0x{int(buf[first_bad]):02x}{int(buf[first_bad + 1]):02x}"
        )
        contents.damage.append(Damage(first_bad, f"{what}; {bad_bytes} bytes skipped up to the next record"))
    if why == CUT:
        length = int(lengths[buf[end + 2]]) if end + 2 < len(buf) else 3
        contents.damage.append(
            Damage(
                end, f"log ends inside a record ({len(buf) - end} of its {length} bytes); records up to there are used"
            )
        )
    fmt_at = offsets[kinds == FMT_TYPE]
    by_id: dict[int, RecordFormat] = {}
    first: dict[int, bytes] = {FMT_TYPE: FMT_BODY}  # the first FMT body of each type
    for at, row in zip(fmt_at.tolist(), _windows(buf, fmt_at, FMT_DTYPE), strict=True):
        type_id, body = int(row["Type"]), row.tobytes()
        if type_id in first:
            if body[:22] != first[type_id][:22]:  # type, length, name, format: the columns may be padded otherwise
                contents.damage.append(Damage(at, f"FMT redefining type {type_id} refused; its first definition holds"))
            continue
        first[type_id] = body
        name = field_text(bytes(row["Name"]))
        if name in wanted:
            try:
                by_id[type_id] = record_format(row, wanted[name])
            except ValueError as exc:
                contents.damage.append(Damage(at, f"FMT for type {type_id} refused ({exc}); its records are not read"))
    contents.formats = {fmt.name: fmt for fmt in by_id.values()}
    for name in wanted:
        fmt = contents.formats.get(name)
        if fmt is None:
            continue
        positions = np.flatnonzero(kinds == fmt.type_id)
        contents.records[name] = _windows(buf, offsets[positions], fmt.dtype)
        contents.positions[name] = positions
    contents.damage.sort(key=lambda d: d.offset)
    return contents


def warm() -> None:
    """Load (or, the first time, compile) the record walk now: a replay's start-up, not its decoding."""
    record_index(np.zeros(0, dtype=np.uint8), np.zeros(256, dtype=np.int64))
