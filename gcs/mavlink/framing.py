"""MAVLink framing that survives bad bytes, and checks every packet without decoding it.

pymavlink's own stream parser trusts a frame's length byte: after a truncated frame or a
flipped length it swallows the start of the next, intact packet. This decoder finds
frame candidates itself, checks each one's CRC (with the type's CRC_EXTRA) and on any failure
moves on by ONE byte from the candidate's start, so every intact packet after damage still
decodes. MAVLink 1 and 2 are accepted per packet.

Checking is not decoding: `frames()` gives each intact packet as its bytes and header (a
`Frame`), and only what needs the fields builds pymavlink's message object
(gcs.mavlink.decoding), which costs several times the framing (the live link decodes only the
types some part subscribes to, gcs.runtime.link). The CRC is pymavlink's own (CRC-16/MCRF4XX
from fastcrc, which pymavlink requires and checks with), called once per packet on its bytes.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field
from typing import TypeAlias

from fastcrc import crc16

from gcs.mavlink.decoding import decode
from gcs.mavlink.dialect import MARKER_V1, MARKER_V2, MAVLinkMessage, mavlink
from gcs.mavlink.tlog import SIGNED

_MCRF4XX = crc16.mcrf4xx
#: message id → (name, CRC_EXTRA as one byte, largest payload)
_TYPES: dict[int, tuple[str, bytes, int]] = {
    msgid: (cls.msgname, bytes((cls.crc_extra,)), cls.unpacker.size) for msgid, cls in mavlink.mavlink_map.items()
}
_MARKERS = (MARKER_V1, MARKER_V2)
#: Gaps in sequence numbers remembered per (sysid, compid), so a reboot seen later can take its own
#: back (`MavlinkDecoder.restart_sequence`): at 1000 packets/s and 10 % loss, the last 0.3 s.
GAPS_KEPT = 32


#: One intact packet: (its bytes as received, its type, sysid, compid from its header). A plain
#: tuple: a NamedTuple costs ~20 times as much to build, once per packet.
Frame: TypeAlias = tuple[bytes, str, int, int]


@dataclass
class FramingCounters:
    """What the decoder saw. `lost` is per (sysid, compid): packets missing by sequence number."""

    packets: int = 0
    crc_errors: int = 0
    malformed: int = 0  # frame candidates rejected before the CRC (impossible length or flags)
    bytes_skipped: int = 0  # bytes that belonged to no valid packet
    unknown: int = 0  # frame candidates with a message id outside the dialect (skipped)
    lost: dict[tuple[int, int], int] = field(default_factory=dict)
    #: per (sysid, compid): packets whose sequence number went back or repeated (by 0 to 128): the network
    #: reordering, a restart, or two senders with one id interleaving (gcs.runtime.sequence_watch)
    stepped_back: dict[tuple[int, int], int] = field(default_factory=dict)
    mavlink1: int = 0
    mavlink2: int = 0


class MavlinkDecoder:
    """Incremental: give it bytes in any chunking, get whole packets back (`frames`) or their
    decoded messages (`feed`)."""

    def __init__(self) -> None:
        self._buf = b""
        self._last_seq: dict[tuple[int, int], int] = {}
        #: per (sysid, compid): the latest gaps counted as lost, (host monotonic s, packets)
        self._gaps: dict[tuple[int, int], deque[tuple[float, int]]] = {}
        self.counters = FramingCounters()

    def feed(self, data: bytes, final: bool = False) -> list[MAVLinkMessage]:
        """The messages `data` completes, decoded."""
        return [decode(packet) for packet, _, _, _ in self.frames(data, final)]

    def new_stream(self) -> None:
        """The bytes that follow come from a new connection (a redialled TCP peer, a reopened
        port). The half frame the old one ended with is dropped (counted as skipped), not joined
        to the new bytes into a CRC error; and the sequence numbers are forgotten: the gap across
        a reconnection is not loss on the link (the peer may have restarted at 0, and a gap of
        more than 255 packets wraps), so it used to count an arbitrary 0-127 packets lost."""
        self.counters.bytes_skipped += len(self._buf)
        self._buf = b""
        self._last_seq.clear()
        self._gaps.clear()

    def last_sequence(self, key: tuple[int, int]) -> int | None:
        """Sender `key`'s last sequence number on this stream (None: none since it began)."""
        return self._last_seq.get(key)

    def restart_sequence(self, key: tuple[int, int], since: float) -> int:
        """Sender `key` rebooted: its sequence numbers started again, on a link that stayed open
        (a UDP port), so the jump from the old boot's number to the new one's was counted as an
        arbitrary 0-127 packets lost. Take back every gap counted for it from host monotonic time
        `since` (the old boot's last reading of its clock, gcs.runtime.vehicle) on: the jump
        cannot be told from a gap just before or after it. Returns the packets taken back."""
        gaps = self._gaps.get(key)
        if not gaps:
            return 0
        taken = sum(n for at, n in gaps if at >= since)
        kept = [(at, n) for at, n in gaps if at < since]
        gaps.clear()
        gaps.extend(kept)
        if taken:
            self.counters.lost[key] -= taken
        return taken

    def frames(self, data: bytes, final: bool = False) -> list[Frame]:
        """The packets `data` completes, CRC-checked and counted. With `final` (end of a
        datagram or of a file) an incomplete candidate at the end is given up on instead of
        waited for."""
        buf = self._buf + data if self._buf else bytes(data)
        out: list[Frame] = []
        i = self._scan(buf, 0, final, out)
        self._buf = buf[i:] if i < len(buf) else b""
        return out

    def datagram_frames(self, datagrams: list[bytes]) -> list[Frame]:
        """`frames(d, final=True)` of each datagram in turn, in one list: a UDP socket's reads of
        one wake-up. A datagram that holds one whole packet (the usual) is checked without the
        scan's loop; the rest of one that holds more, or damage, goes through the scan."""
        if self._buf:  # a stream's leftover (never after a datagram, which is final)
            return [frame for data in datagrams for frame in self.frames(data, final=True)]
        out: list[Frame] = []
        try_frame, scan, c = self._try_frame, self._scan, self.counters
        for data in datagrams:
            n = len(data)
            if not n:
                continue
            if data[0] not in _MARKERS:
                scan(data, 0, True, out)
                continue
            verdict = try_frame(data, 0, n, True)
            if isinstance(verdict, tuple):
                out.append(verdict)
                if len(verdict[0]) < n:
                    scan(data, len(verdict[0]), True, out)
            else:  # rejected candidate (final: never "wait"): resynchronise one byte on, as `frames`
                c.bytes_skipped += 1
                scan(data, 1, True, out)
        return out

    def _scan(self, buf: bytes, i: int, final: bool, out: list[Frame]) -> int:
        """Frame buf from i on into out; returns where the bytes not yet framed start."""
        c = self.counters
        n = len(buf)
        while i < n:
            if buf[i] not in _MARKERS:
                start = self._next_marker(buf, i)
                if start < 0:
                    c.bytes_skipped += n - i
                    i = n
                    break
                c.bytes_skipped += start - i
                i = start
            verdict = self._try_frame(buf, i, n, final)
            if verdict is None:  # need more bytes
                break
            if isinstance(verdict, int):  # rejected candidate: resynchronise one byte on
                c.bytes_skipped += 1
                i += 1
                continue
            out.append(verdict)
            i += len(verdict[0])
        return i

    @staticmethod
    def _next_marker(buf: bytes, i: int) -> int:
        a = buf.find(MARKER_V1, i)
        b = buf.find(MARKER_V2, i)
        if a < 0:
            return b
        if b < 0:
            return a
        return min(a, b)

    def _try_frame(self, buf: bytes, i: int, n: int, final: bool) -> Frame | int | None:
        """The frame at i if it is valid; None to wait for more bytes; 0 to reject."""
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
        known = _TYPES.get(msgid)
        if known is None:
            # No CRC_EXTRA to check it with, so indistinguishable from garbage: skip it.
            c.unknown += 1
            return 0
        name, crc_extra, size = known
        if plen > size or (v2 and plen == 0):
            c.malformed += 1
            return 0
        if n - i < length:
            return 0 if final else None
        end = i + header + plen
        if _MCRF4XX(crc_extra, _MCRF4XX(buf[i + 1 : end], 0xFFFF)) != buf[end] | (buf[end + 1] << 8):
            c.crc_errors += 1
            return 0
        c.packets += 1
        if v2:
            c.mavlink2 += 1
        else:
            c.mavlink1 += 1
        self._count_sequence(sysid, compid, seq)
        return buf[i : i + length], name, sysid, compid

    def _count_sequence(self, sysid: int, compid: int, seq: int) -> None:
        key = (sysid, compid)
        last = self._last_seq.get(key)
        if last is not None:
            missing = (seq - last - 1) & 0xFF
            if missing and missing < 128:
                self.counters.lost[key] = self.counters.lost.get(key, 0) + missing
                gaps = self._gaps.get(key)
                if gaps is None:
                    gaps = self._gaps[key] = deque(maxlen=GAPS_KEPT)
                gaps.append((time.monotonic(), missing))
            elif missing:  # a step back is no loss
                self.counters.stepped_back[key] = self.counters.stepped_back.get(key, 0) + 1
        self._last_seq[key] = seq
