"""MAVLink framing that survives bad bytes.

pymavlink's own stream parser trusts a frame's length byte: after a truncated frame or a
flipped length it swallows the start of the next, intact packet. This decoder finds
frame candidates itself, lets pymavlink decode and check each (CRC with CRC_EXTRA), and on
any failure moves on by ONE byte from the candidate's start, so every intact packet after
damage still decodes. MAVLink 1 and 2 are accepted per packet.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from gcs.mavlink.dialect import MARKER_V1, MARKER_V2, MAVError, MAVLink, MAVLinkMessage, mavlink
from gcs.mavlink.tlog import SIGNED

_MAP = mavlink.mavlink_map


@dataclass
class FramingCounters:
    """What the decoder saw. `lost` is per (sysid, compid): packets missing by sequence number."""

    packets: int = 0
    crc_errors: int = 0
    malformed: int = 0  # frame candidates rejected before the CRC (impossible length or flags)
    bytes_skipped: int = 0  # bytes that belonged to no valid packet
    unknown: int = 0  # frame candidates with a message id outside the dialect (skipped)
    lost: dict[tuple[int, int], int] = field(default_factory=dict)
    mavlink1: int = 0
    mavlink2: int = 0


class MavlinkDecoder:
    """Incremental decoder: feed() it bytes in any chunking, get whole messages back."""

    def __init__(self) -> None:
        self._mav = MAVLink(None)
        self._buf = bytearray()
        self._last_seq: dict[tuple[int, int], int] = {}
        self.counters = FramingCounters()

    def feed(self, data: bytes, final: bool = False) -> list[MAVLinkMessage]:
        """Decode what `data` completes. With `final` (end of a datagram or of a file) an
        incomplete candidate at the end is given up on instead of waited for."""
        buf = self._buf
        buf += data
        out: list[MAVLinkMessage] = []
        c = self.counters
        n = len(buf)
        i = 0
        while i < n:
            start = self._next_marker(buf, i)
            if start < 0:
                c.bytes_skipped += n - i
                i = n
                break
            if start > i:
                c.bytes_skipped += start - i
                i = start
            verdict = self._try_frame(buf, i, n, final)
            if verdict is None:  # need more bytes
                break
            if isinstance(verdict, int):  # rejected candidate: resynchronise one byte on
                c.bytes_skipped += 1
                i += 1
                continue
            msg, length = verdict
            out.append(msg)
            i += length
        del buf[:i]
        return out

    @staticmethod
    def _next_marker(buf: bytearray, i: int) -> int:
        a = buf.find(MARKER_V1, i)
        b = buf.find(MARKER_V2, i)
        if a < 0:
            return b
        if b < 0:
            return a
        return min(a, b)

    def _try_frame(self, buf: bytearray, i: int, n: int, final: bool) -> tuple[MAVLinkMessage, int] | int | None:
        """(message, length) for a valid frame at i; None to wait for more bytes; 0 to reject."""
        c = self.counters
        v2 = buf[i] == MARKER_V2
        header = 10 if v2 else 6
        if n - i < header:
            return 0 if final else None
        plen = buf[i + 1]
        if v2:
            flags = buf[i + 2]
            if flags & ~SIGNED:
                c.malformed += 1
                return 0
            msgid = buf[i + 7] | (buf[i + 8] << 8) | (buf[i + 9] << 16)
            seq, sysid, compid = buf[i + 4], buf[i + 5], buf[i + 6]
            length = header + plen + 2 + (13 if flags & SIGNED else 0)
        else:
            msgid = buf[i + 5]
            seq, sysid, compid = buf[i + 2], buf[i + 3], buf[i + 4]
            length = header + plen + 2
        cls = _MAP.get(msgid)
        if cls is None:
            # No CRC_EXTRA to check it with, so indistinguishable from garbage: skip it.
            c.unknown += 1
            return 0
        if plen > cls.unpacker.size or (v2 and plen == 0):
            c.malformed += 1
            return 0
        if n - i < length:
            return 0 if final else None
        try:
            msg = self._mav.decode(buf[i : i + length])
        except MAVError:
            c.crc_errors += 1
            return 0
        c.packets += 1
        if v2:
            c.mavlink2 += 1
        else:
            c.mavlink1 += 1
        self._count_sequence(sysid, compid, seq)
        return msg, length

    def _count_sequence(self, sysid: int, compid: int, seq: int) -> None:
        key = (sysid, compid)
        last = self._last_seq.get(key)
        if last is not None:
            missing = (seq - last - 1) & 0xFF
            if missing and missing < 128:  # a large jump backwards is a restart, not loss
                self.counters.lost[key] = self.counters.lost.get(key, 0) + missing
        self._last_seq[key] = seq
