"""The .tlog record format that Mission Planner, QGroundControl and MAVProxy all write:
an 8-byte big-endian microsecond UNIX timestamp, then one raw MAVLink packet, repeated.
There is no header and no index, so damage is found by the frame structure itself.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from gcs.mavlink.dialect import MARKER_V1, MARKER_V2

TIMESTAMP = struct.Struct(">Q")
#: MAVLink 2 incompat flag: the packet carries a 13-byte signature.
SIGNED = 0x01


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
    """Iterates (usec, packet) over a .tlog. After iteration, `skipped` counts bytes that were
    not a record (damage) and `truncated_at` is the file offset of an incomplete last record."""

    path: str
    skipped: int = 0
    truncated_at: int | None = None
    damage_offsets: list[int] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.data = Path(self.path).read_bytes()

    def __iter__(self) -> Iterator[tuple[int, bytes]]:
        data, n, i = self.data, len(self.data), 0
        while i + 8 < n:
            length = packet_length(data, i + 8)
            if length is None:
                if not self.damage_offsets or self.damage_offsets[-1] != i - 1:
                    self.damage_offsets.append(i)
                self.skipped += 1
                i += 1
                continue
            end = i + 8 + length
            if end > n:
                self.truncated_at = i
                return
            yield TIMESTAMP.unpack_from(data, i)[0], data[i + 8 : end]
            i = end
        if i < n:
            self.truncated_at = i


def read_tlog_records(path: str | Path) -> TlogRecords:
    return TlogRecords(str(path))


def tlog_record(usec: int, packet: bytes) -> bytes:
    """One record as written to a .tlog."""
    return TIMESTAMP.pack(usec) + packet
