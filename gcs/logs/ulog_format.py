"""The ULog container (PX4 .ulg) read straight into NumPy: the topics asked for as structured
arrays, the parameters, and where the file is damaged.

A 69 s flight is 65,000 messages, almost all data ('D'). pyulog decodes each in Python (about as
long as the three estimators take over the whole flight); here one compiled walk over the message
headers (`message_index`) finds them all, the few definitions, subscriptions ('A') and parameters
are read in Python, and the data messages of each wanted topic are gathered with one NumPy index
and viewed through a dtype built from the topic's 'F' format. The values are pyulog's, field names
included ("gyro_rad[0]", nested types as "a.b"); tests/test_ulog_format.py compares them.

Format (docs.px4.io, "ULog File Format"): a 16-byte header (magic, version, start time µs), then
messages of a uint16 payload size, a type byte and the payload. The definitions (flag bits 'B',
formats 'F', initial parameters 'P', info) end at the first subscription or logged string; a
parameter after that is a change, at the latest data timestamp before it (pyulog's rule). Appended
data (flag bit) is read segment by segment as pyulog reads it.

Damage: a file cut inside a message is read up to that message; a header that is no message's
(type 0, size 0, an unknown type over 10000 bytes) stops the reading unless a sync marker follows,
where it resumes; a data message of an undeclared id or of the wrong size is skipped. `damage`
names the first place, its cause and what was done.
"""

from __future__ import annotations

import struct
from collections.abc import Collection
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from gcs.core.estimators.jit import kernel
from gcs.logs.logfile import InputError
from gcs.logs.offsets import appended

MAGIC = b"ULog\x01\x12\x35"
SYNC = b"\x2f\x73\x13\x20\x25\x0c\xbb\x12"
HEADER_SIZE = 16
#: ULog scalar type → little-endian NumPy type (pyulog's: bool and char as int8).
TYPES = {
    "int8_t": "<i1", "uint8_t": "<u1", "int16_t": "<i2", "uint16_t": "<u2", "int32_t": "<i4",
    "uint32_t": "<u4", "int64_t": "<i8", "uint64_t": "<u8", "float": "<f4", "double": "<f8",
    "bool": "<i1", "char": "<i1",
}  # fmt: skip
#: Parameter types with a numeric value: struct codes.
PARAMETER_CODES = {"int32_t": "<i", "float": "<f"}
#: Message types of the format; any other one is skipped (a newer format's), unless implausible.
KNOWN = np.zeros(256, dtype=np.bool_)
KNOWN[[ord(c) for c in "BFIMPQARDLCSO"]] = True
#: An unknown message type with a payload over this is taken for damage (pyulog's rule).
MAX_UNKNOWN_SIZE = 10000
#: message_index's stops
CLEAN, CUT, BAD_HEADER = 0, 1, 2
#: message_index sizes its first index for messages of this many bytes and doubles it when they
#: are shorter (sized for the shortest message, 4 bytes, it took 2.7 times the file's size).
GUESSED_MESSAGE_SIZE = 32
#: Nested types deeper than this are damage (a format naming itself would never end).
MAX_NESTING = 8
#: A data message holds at most this many bytes, so no format has more fields (a hostile array
#: size would otherwise make millions of names).
MAX_FIELDS = 0xFFFF


@kernel
def message_index(
    buf: npt.NDArray[np.uint8], pos: int, end: int, known: npt.NDArray[np.bool_]
) -> tuple[npt.NDArray[np.int64], int, int]:
    """Offsets of the messages from pos on, walking their headers, and where and why the walk
    stopped: CLEAN at `end`, CUT at a message that does not end by `end`, BAD_HEADER at one that
    is no message (type 0, payload size 0, an unknown type with a payload over MAX_UNKNOWN_SIZE)."""
    offsets = np.empty((end - pos) // GUESSED_MESSAGE_SIZE + 16, dtype=np.int64)
    n = 0
    while pos < end:
        if pos + 3 > end:
            return offsets[:n], pos, CUT
        size = int(buf[pos]) | (int(buf[pos + 1]) << 8)
        kind = buf[pos + 2]
        if kind == 0 or size == 0 or (not known[kind] and size > MAX_UNKNOWN_SIZE):
            return offsets[:n], pos, BAD_HEADER
        if pos + 3 + size > end:
            return offsets[:n], pos, CUT
        offsets = appended(offsets, n, pos)
        n += 1
        pos += 3 + size
    return offsets[:n], pos, CLEAN


@dataclass(frozen=True)
class Damage:
    """Where the file is damaged, what was found there and what the reader did about it."""

    offset: int
    cause: str


@dataclass
class UlogContents:
    """What `read_ulog` found. `topics[(name, multi_id)]`: every data row of that topic in file
    order (structured, pyulog's field names); `changed_parameters`: (timestamp µs, name, value);
    `info`: the information messages ('I': sys_name, ver_hw, ver_sw ..., uint32_t ones in decimal);
    `dropouts`: where the logger lost data and for how long."""

    start_us: int
    topics: dict[tuple[str, int], npt.NDArray[np.void]] = field(default_factory=dict)
    initial_parameters: dict[str, float] = field(default_factory=dict)
    changed_parameters: list[tuple[int, str, float]] = field(default_factory=list)
    info: dict[str, str] = field(default_factory=dict)
    damage: list[Damage] = field(default_factory=list)
    #: the logger's dropouts ('O': it lost data, its buffer full): (offset, duration ms)
    dropouts: list[tuple[int, int]] = field(default_factory=list)


def _text(payload: bytes) -> str:
    return payload.decode("utf-8", "ignore")


def _format(payload: bytes) -> tuple[str, list[tuple[str, int, str]]]:
    """An 'F' message: "name:type field;type[n] field;..." → (name, [(type, array length, field)])."""
    name, _, body = _text(payload).partition(":")
    fields = []
    for item in filter(None, body.split(";")):
        kind, fname = item.split(" ")[:2]
        base, _, count = kind.partition("[")
        fields.append((base, int(count.rstrip("]")) if count else 0, fname))
    return name, fields


Formats = dict[str, list[tuple[str, int, str]]]


def _flatten(formats: Formats, name: str, prefix: str = "", depth: int = 0) -> list[tuple[str, str]]:
    """The scalar fields of format `name`, nested types and arrays spelled out as pyulog does."""
    if depth > MAX_NESTING:
        raise ValueError(f"format {name} nested deeper than {MAX_NESTING}")
    out: list[tuple[str, str]] = []
    for kind, count, fname in formats[name]:
        for full in [f"{prefix}{fname}[{i}]" for i in range(min(count, MAX_FIELDS + 1))] if count else [prefix + fname]:
            if kind in TYPES:
                out.append((full, TYPES[kind]))
            else:
                out.extend(_flatten(formats, kind, full + ".", depth + 1))
            if len(out) > MAX_FIELDS:
                raise ValueError(f"format {name} has more fields than a message has bytes")
    return out


def topic_dtype(formats: Formats, name: str) -> np.dtype[np.void]:
    """A topic's row as pyulog reads it: packed, little-endian, trailing padding left out."""
    fields = _flatten(formats, name)
    while fields and fields[-1][0].startswith("_padding"):
        fields.pop()
    return np.dtype(fields)


def _parameter(payload: bytes) -> tuple[str, float] | None:
    """A 'P' message: (name, value) for a numeric one, else None."""
    key_len = payload[0]
    kind, _, name = _text(payload[1 : 1 + key_len]).partition(" ")
    code = PARAMETER_CODES.get(kind)
    if code is None or len(payload) - 1 - key_len != struct.calcsize(code):
        return None
    return name, float(struct.unpack_from(code, payload, 1 + key_len)[0])


def _info(payload: bytes) -> tuple[str, str] | None:
    """An 'I' message: (name, text) for a text one ("char[3] sys_name" "PX4") or a uint32_t one
    in decimal ("uint32_t ver_sw_release"), else None."""
    key_len = payload[0]
    kind, _, name = _text(payload[1 : 1 + key_len]).partition(" ")
    value = payload[1 + key_len :]
    if kind == "uint32_t" and len(value) == 4:
        return name, str(struct.unpack("<I", value)[0])
    if not kind.startswith("char["):
        return None
    return name, _text(value).split("\0", 1)[0]


def _segments(buf: npt.NDArray[np.uint8], contents: UlogContents) -> list[tuple[int, int]]:
    """(start, end) of the stretches of messages: the whole file, or with appended data (flag
    bits) each part up to the next appended offset, as pyulog reads them."""
    n = len(buf)
    if n < HEADER_SIZE + 3 + 40 or buf[HEADER_SIZE + 2] != ord("B"):
        return [(HEADER_SIZE, n)]
    flags = buf[HEADER_SIZE + 3 : HEADER_SIZE + 3 + 40].tobytes()
    incompat = flags[8:16]
    if incompat[0] & ~1 or any(incompat[1:]):
        raise ValueError("unknown incompatible flag set")
    appended = [o for o in struct.unpack_from("<3Q", flags, 16) if o] if incompat[0] & 1 else []
    bounds, start = [], HEADER_SIZE
    for offset in appended:
        if not start < offset <= n:
            contents.damage.append(Damage(HEADER_SIZE, f"appended-data offset {offset} outside the file; ignored"))
            break
        bounds.append((start, offset))
        start = offset
    return [*bounds, (start, n)]


def _message_offsets(buf: npt.NDArray[np.uint8], contents: UlogContents) -> npt.NDArray[np.int64]:
    """Every whole message's offset, in file order (damage noted in contents)."""
    parts = []
    for start, end in _segments(buf, contents):
        pos = start
        while True:
            offsets, pos, why = message_index(buf, pos, end, KNOWN)
            parts.append(offsets)
            if why == CLEAN or (why == CUT and end < len(buf)):  # an appended part begins there
                break
            if why == CUT:
                present = len(buf) - pos
                length = 3 if present < 3 else 3 + int(buf[pos]) + (int(buf[pos + 1]) << 8)
                contents.damage.append(
                    Damage(
                        pos,
                        f"log ends inside a message ({present} of its {length} bytes); samples up to there are used",
                    )
                )
                return np.concatenate(parts)
            size = int(buf[pos]) | (int(buf[pos + 1]) << 8)
            what = f"damaged data (message type 0x{int(buf[pos + 2]):02x}, {size} bytes)"
            sync = buf[pos + 1 : end].tobytes().find(SYNC)
            if sync < 0:
                contents.damage.append(Damage(pos, f"{what}; samples up to there are used"))
                return np.concatenate(parts)
            resume = pos + 1 + sync + len(SYNC)
            contents.damage.append(Damage(pos, f"{what}; skipped to the sync marker ending at offset {resume}"))
            pos = resume
    return np.concatenate(parts)


def read_ulog(path: str, wanted: Collection[str]) -> UlogContents:
    """The topics named in `wanted` (every instance), the parameters and the damage of the .ulg
    at path; InputError when it cannot be read or is no ULog file."""
    try:
        buf = np.fromfile(path, dtype=np.uint8)
    except OSError as exc:
        raise InputError(f"{path}: offset 0: cannot read ({exc.strerror})") from None
    if len(buf) < HEADER_SIZE or buf[:7].tobytes() != MAGIC:
        raise InputError(f"{path}: offset 0: not a ULog file (no ULog header)")
    contents = UlogContents(int(buf[8:16].view("<u8")[0]))
    try:
        offsets = _message_offsets(buf, contents)
    except ValueError as exc:
        raise InputError(f"{path}: offset 0: not a ULog file ({exc})") from None
    sizes = buf[offsets].astype(np.int64) | (buf[offsets + 1].astype(np.int64) << 8)
    types = buf[offsets + 2]
    data = types == ord("D")
    formats: Formats = {}
    subscriptions: list[tuple[int, int, str, int]] = []  # (offset, msg_id, name, multi_id)
    parameters: list[tuple[int, str, float]] = []  # changes: (offset, name, value)
    in_definitions = True
    for k in np.flatnonzero(~data).tolist():
        at, kind = int(offsets[k]), chr(types[k])
        payload = buf[at + 3 : at + 3 + int(sizes[k])].tobytes()
        in_definitions = in_definitions and kind not in "ALC"
        try:
            if kind == "F" and in_definitions:
                name, fields = _format(payload)
                formats[name] = fields
            elif kind == "P":
                parameter = _parameter(payload)
                if parameter is not None and in_definitions:
                    contents.initial_parameters[parameter[0]] = parameter[1]
                elif parameter is not None:
                    parameters.append((at, *parameter))
            elif kind == "I":
                info = _info(payload)
                if info is not None:
                    contents.info.setdefault(*info)
            elif kind == "O":
                contents.dropouts.append((at, struct.unpack_from("<H", payload)[0]))
            elif kind == "A":
                multi_id, msg_id = struct.unpack_from("<BH", payload)
                subscriptions.append((at, msg_id, _text(payload[3:]), multi_id))
        except (ValueError, IndexError, struct.error) as exc:
            contents.damage.append(Damage(at, f"unreadable '{kind}' message ({exc}); skipped"))
    _gather(buf, offsets[data], sizes[data], formats, subscriptions, set(wanted), contents, parameters)
    contents.damage.sort(key=lambda d: d.offset)
    return contents


def _gather(
    buf: npt.NDArray[np.uint8],
    at: npt.NDArray[np.int64],
    sizes: npt.NDArray[np.int64],
    formats: Formats,
    subscriptions: list[tuple[int, int, str, int]],
    wanted: set[str],
    contents: UlogContents,
    parameters: list[tuple[int, str, float]],
) -> None:
    """The data messages at offsets `at` into contents.topics (the wanted ones), each to the
    subscription its id had there; the changed parameters stamped with the latest wanted data
    timestamp before them (pyulog's last timestamp; the log's start before any)."""
    short = sizes < 2
    low, high = buf[at + 3].astype(np.int64), buf[np.minimum(at + 4, len(buf) - 1)].astype(np.int64)
    msg_id = np.where(short, -1, low | (high << 8))
    # the subscription each message belongs to: the last 'A' of its id before it
    keys = np.array([(m << 40) | o for o, m, _, _ in subscriptions], dtype=np.int64)
    order = np.argsort(keys, kind="stable")
    sub = np.searchsorted(keys[order], (msg_id << 40) | at, side="right") - 1
    found = (sub >= 0) & ~short
    sub = np.where(found, order[np.maximum(sub, 0)], -1)
    found &= np.array([m for _, m, _, _ in subscriptions] or [0], dtype=np.int64)[np.maximum(sub, 0)] == msg_id
    if not found.all():
        k = int(np.argmin(found))
        cause = f"data for message id {int(msg_id[k])}, which no subscription declared; skipped"
        contents.damage.append(Damage(int(at[k]), cause))
    stamps: list[tuple[npt.NDArray[np.int64], npt.NDArray[np.uint64]]] = []
    by_topic: dict[tuple[str, int], list[int]] = {}
    for index, (_, _, name, multi_id) in enumerate(subscriptions):
        if name in wanted:
            by_topic.setdefault((name, multi_id), []).append(index)
    for (name, multi_id), indices in by_topic.items():
        mine = found & np.isin(sub, indices)
        try:
            dtype = topic_dtype(formats, name)
        except (KeyError, ValueError) as exc:
            if mine.any():
                contents.damage.append(Damage(int(at[mine][0]), f"{name} has no usable format ({exc}); skipped"))
            continue
        fits = sizes[mine] - 2 == dtype.itemsize
        rows_at = at[mine]
        if not fits.all():
            k = int(np.argmin(fits))
            contents.damage.append(
                Damage(
                    int(rows_at[k]),
                    f"{name} message of {int(sizes[mine][k]) - 2} bytes where its format has {dtype.itemsize}; skipped",
                )  # fmt: skip
            )
            rows_at = rows_at[fits]
        if not len(rows_at):
            continue
        windows = np.lib.stride_tricks.as_strided(buf, (len(buf) - dtype.itemsize + 1, dtype.itemsize), (1, 1))
        rows = windows[rows_at + 5].view(dtype).reshape(-1)  # one row copied per message
        contents.topics[(name, multi_id)] = rows
        if "timestamp" in (dtype.names or ()):
            stamps.append((rows_at, rows["timestamp"].astype(np.uint64)))
    if not parameters:
        return
    where = np.array([o for o, _, _ in parameters], dtype=np.int64)
    latest = np.full(len(parameters), contents.start_us, dtype=np.uint64)
    if stamps:
        offsets = np.concatenate([o for o, _ in stamps])
        order = np.argsort(offsets, kind="stable")
        running = np.maximum.accumulate(np.concatenate([t for _, t in stamps])[order])
        before = np.searchsorted(offsets[order], where) - 1
        latest = np.where(before >= 0, np.maximum(running[np.maximum(before, 0)], latest), latest)
    contents.changed_parameters = [
        (int(t), name, value) for t, (_, name, value) in zip(latest.tolist(), parameters, strict=True)
    ]


def warm() -> None:
    """Load (or, the first time, compile) the header walk now: a replay's start-up, not its decoding."""
    message_index(np.zeros(0, dtype=np.uint8), 0, 0, np.zeros(256, dtype=np.bool_))
