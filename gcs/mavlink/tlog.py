"""The .tlog record format that Mission Planner, QGroundControl and MAVProxy all write:
an 8-byte big-endian microsecond UNIX timestamp, then one raw MAVLink packet, repeated.
There is no header and no index, so damage is found by the frame structure itself.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from gcs.mavlink.dialect import MARKER_V1, MARKER_V2

TIMESTAMP = struct.Struct(">Q")
#: MAVLink 2 incompat flag: the packet carries a 13-byte signature.
SIGNED = 0x01
#: Bytes read at a time, and the longest possible record (timestamp + signed MAVLink 2 packet).
CHUNK = 1 << 20
MAX_RECORD = 8 + 12 + 255 + 13
#: A paced replay (gcs replay --speed, a .tlog as a link) plays a record due further than this
#: (s of replay time) ahead or behind at once, and paces on from it: a recording gap is not waited
#: out, and a damaged timestamp (one flipped bit put a hop tlog's record 68e9 s ahead) neither
#: stops the replay for ever nor, once past, lets the rest run flat out.
MAX_WAIT_S = 60.0


def packet_length(buf: bytes | bytearray, start: int) -> int | None:
    """Length of the MAVLink packet starting at buf[start], from its header; None if the
    byte there is not a start-of-frame marker or the header is not complete."""
    if start + 3 > len(buf):
        return None
    marker = buf[start]
    if marker == MARKER_V1:
        return 8 + buf[start + 1]
    if marker == MARKER_V2:
        return 12 + buf[start + 1] + (13 if buf[start + 2] & SIGNED else 0)
    return None


@dataclass
class TlogRecords:
    """Iterates (usec, packet) over a .tlog, reading the file in chunks (a flight-hour at 400 Hz
    is over 100 MB). `records()` also gives each packet's file offset. After iteration, `skipped`
    counts bytes that were not a record (damage) and `truncated_at` is the file offset of an
    incomplete last record; `size` is the file's size when it was opened."""

    path: str
    skipped: int = 0
    truncated_at: int | None = None
    damage_offsets: list[int] = field(default_factory=list)
    size: int = 0

    def __post_init__(self) -> None:
        self.size = os.stat(self.path).st_size  # OSError now, not mid-iteration, if it is missing

    def __iter__(self) -> Iterator[tuple[int, bytes]]:
        for _, usec, packet in self.records():
            yield usec, packet

    def records(self) -> Iterator[tuple[int, int, bytes]]:
        """(file offset of the packet, usec, packet) for every complete record."""
        with open(self.path, "rb") as fh:
            data, base, i = b"", 0, 0  # data holds the file from offset `base`
            eof = False
            last_skipped = -2  # file offset of the last byte skipped: a run of them is one place
            while True:
                if len(data) - i < MAX_RECORD and not eof:
                    chunk = fh.read(CHUNK)
                    eof = len(chunk) < CHUNK
                    data, base, i = data[i:] + chunk, base + i, 0
                if i + 8 >= len(data):
                    break
                length = packet_length(data, i + 8)
                if length is None:
                    if base + i != last_skipped + 1:
                        self.damage_offsets.append(base + i)
                    last_skipped = base + i
                    self.skipped += 1
                    i += 1
                    continue
                end = i + 8 + length
                if end > len(data):
                    self.truncated_at = base + i
                    return
                yield base + i + 8, TIMESTAMP.unpack_from(data, i)[0], data[i + 8 : end]
                i = end
            if i < len(data):
                self.truncated_at = base + i

    def damage(self, used: str) -> str | None:
        """After iteration, one line saying where the file is damaged (`used`: what was done with
        the records before it, "replayed up to it"), or None for an intact file."""
        if self.truncated_at is not None:
            return f"{self.path}: offset {self.truncated_at}: last record incomplete; {used}"
        if self.damage_offsets:
            first, places = self.damage_offsets[0], len(self.damage_offsets)
            return f"{self.path}: offset {first}: {self.skipped} damaged bytes skipped ({places} places)"
        return None


def read_tlog_records(path: str | Path) -> TlogRecords:
    return TlogRecords(str(path))


def tlog_wall_time(wall_time: float) -> float:
    """A host UNIX time (s) as a tlog record keeps it: whole µs, the low 2 bits (link bits) cleared.
    What a live consumer uses where a replay of the recording reads (usec & ~3) / 1e6."""
    return (int(wall_time * 1e6) & ~3) / 1e6


def tlog_record(usec: int, packet: bytes) -> bytes:
    """One record as written to a .tlog."""
    return TIMESTAMP.pack(usec) + packet
