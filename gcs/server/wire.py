"""The /ws/live wire format: binary frames of float arrays, one WebSocket message per client per tick.

JSON cost the loop a `round()` and a decimal string per number per frame, and the page a
`JSON.parse` of every one; here a frame is the numbers' own bytes. A message is one or more
frames back to back (a client that fell behind gets everything queued for it in one message);
each frame says its own length, so a reader walks them without knowing their kinds.

All little-endian, every block a multiple of 8 bytes, so a reader maps the arrays in place
(JavaScript's `Float64Array(buffer, offset, n)` needs an offset aligned to 8):

    frame    u32 length (bytes, this header included) · u8 kind · u8 version · u16 count
    kind 1   points: u32 seq · u32 0 · f64 server_time (host monotonic s), then `count` series:
    series   u16 name length · u16 0 · u32 n · name (UTF-8, zero-padded to 8) ·
             f64 t[n] (vehicle s, at µs: as GET /api/history) · f32 roll[n] · f32 pitch[n] ·
             f32 yaw[n] (degrees, as the live store keeps them) · zero padding to 8
    kind 2   message: a JSON object (UTF-8, strict: `core.strict_json`), zero-padded to 8

The page's decoder is web/public/wire.js; `decode` is the one for Python readers (bench/, tests).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from itertools import repeat

from gcs.core import strict_json

VERSION = 1
POINTS = 1
MESSAGE = 2

_FRAME = struct.Struct("<IBBH")  # length, kind, version, count
_POINTS = struct.Struct("<IId")  # seq, 0, server_time
_SERIES = struct.Struct("<HHI")  # name length, 0, n
_PAD = b"\0" * 8


def _padded(data: bytes) -> bytes:
    return data + _PAD[: -len(data) % 8]


def wire_times(t: Iterable[float]) -> list[float]:
    """Vehicle times as the page receives them, live or in history: rounded to the µs (Python's
    correctly rounded `round`; np.round can differ by an ulp)."""
    return list(map(round, t, repeat(6)))


def points_frame(seq: int, server_time: float, points: Mapping[str, Sequence[Sequence[float]]]) -> bytes:
    """One points frame from per-source columns [t, roll, pitch, yaw] (s, degrees)."""
    parts = [b"", _POINTS.pack(seq, 0, server_time)]
    for source, (t, roll, pitch, yaw) in points.items():
        name = source.encode()
        parts.append(_SERIES.pack(len(name), 0, len(t)) + _padded(name))
        n = len(t)
        parts.append(struct.pack(f"<{n}d", *wire_times(t)))
        parts.append(_padded(struct.pack(f"<{3 * n}f", *roll, *pitch, *yaw)))
    size = _FRAME.size + sum(len(p) for p in parts)
    parts[0] = _FRAME.pack(size, POINTS, VERSION, len(points))
    return b"".join(parts)


def message_frame(message: Mapping[str, object]) -> bytes:
    """A control message (a gain change, ...) in order with the points around it."""
    body = _padded(strict_json.dumps(message, separators=(",", ":")).encode())
    return _FRAME.pack(_FRAME.size + len(body), MESSAGE, VERSION, 0) + body


@dataclass(frozen=True, slots=True)
class PointsFrame:
    """A decoded points frame: per source (t, roll, pitch, yaw) tuples (s, degrees)."""

    seq: int
    server_time: float
    points: dict[str, tuple[tuple[float, ...], ...]]


def decode(data: bytes) -> Iterator[PointsFrame | dict]:
    """The frames of one binary message, in order: points, or a control message's JSON object.
    Raises ValueError on a frame that does not fit the message, has an unknown version, or
    carries a non-finite number (the server never sends one). Plain tuples, not numpy arrays:
    a frame holds a few samples per source, and a reader process keeping up with 20 clients
    spends its time per call, not per number (bench.wire)."""
    view = memoryview(data)
    offset = 0
    while offset < len(data):
        size, kind, version, count = _FRAME.unpack_from(view, offset)
        end = offset + size
        if version != VERSION or size < _FRAME.size or end > len(data):
            raise ValueError(f"bad frame at byte {offset}: version {version}, length {size} of {len(data)}")
        body = offset + _FRAME.size
        if kind == POINTS:
            yield _points(view, body, count)
        elif kind == MESSAGE:
            yield strict_json.loads(bytes(view[body:end]).rstrip(b"\0"))
        offset = end


def _points(view: memoryview, offset: int, count: int) -> PointsFrame:
    seq, _, server_time = _POINTS.unpack_from(view, offset)
    offset += _POINTS.size
    points: dict[str, tuple[tuple[float, ...], ...]] = {}
    for _ in range(count):
        name_len, _, n = _SERIES.unpack_from(view, offset)
        offset += _SERIES.size
        name = bytes(view[offset : offset + name_len]).decode()
        offset += name_len + (-name_len % 8)
        t = struct.unpack_from(f"<{n}d", view, offset)
        offset += 8 * n
        rpy = struct.unpack_from(f"<{3 * n}f", view, offset)
        offset += 12 * n + (-12 * n % 8)
        if not all(map(math.isfinite, t + rpy)):
            raise ValueError(f"non-finite number in series {name!r}")
        points[name] = (t, rpy[:n], rpy[n : 2 * n], rpy[2 * n :])
    return PointsFrame(seq, server_time, points)
