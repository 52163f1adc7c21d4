"""MAVLink 2 message signing, as MAVProxy and Mission Planner do it (docs/protocols.md, "Signing").

A packet signed with the 32-byte secret key carries, after its CRC, a link id (1 byte), a
timestamp (6 bytes, 10 µs units since 2015-01-01) and the first 6 bytes of
SHA-256(key + header + payload + CRC + link id + timestamp). The key is SHA-256 of a passphrase
(MAVProxy's `signing setup PASSPHRASE`, Mission Planner) or a 32-byte key file.

Outgoing packets are signed by pymavlink (`MAVLink.signing` of the station's encoder). Incoming
ones are checked here, per packet, on the bytes as received: the signature, and the timestamp
strictly increasing per stream (link id, sysid, compid); a new stream may start at most a minute
behind the newest timestamp seen (replay protection, the rule of the MAVLink spec and pymavlink).
When signing is required an unsigned or badly signed packet is rejected and counted by reason;
when it is optional it is accepted and counted (flagged). RADIO_STATUS is accepted unsigned
either way: a SiK radio injects it itself and cannot sign it (MAVProxy does the same).
"""

from __future__ import annotations

import hashlib
import struct
import time
from dataclasses import dataclass, field
from pathlib import Path

from gcs.mavlink.dialect import MARKER_V2, Encoder, MAVLinkMessage, mavlink

#: Signing timestamps count 10 µs units from 2015-01-01 00:00:00 UTC.
EPOCH_2015 = 1420070400
KEY_BYTES = 32
SIGNATURE_BYTES = 13  # link id 1 + timestamp 6 + signature 6
#: A new stream may start this far (10 µs units) behind the newest timestamp: one minute.
NEW_STREAM_SLACK = 6_000_000
#: Packets a radio injects unsigned.
UNSIGNED_ALLOWED = frozenset({"RADIO_STATUS", "RADIO"})
_FLAG_SIGNED = mavlink.MAVLINK_IFLAG_SIGNED


class SigningKeyError(ValueError):
    """A key file or passphrase that cannot be a signing key; the message says why."""


def key_from_passphrase(passphrase: str) -> bytes:
    """SHA-256 of the passphrase, as MAVProxy and Mission Planner derive it."""
    if not passphrase:
        raise SigningKeyError("an empty passphrase is not a signing key")
    return hashlib.sha256(passphrase.encode("utf-8")).digest()


def key_from_file(path: str | Path) -> bytes:
    """A key file: 32 raw bytes, or the key as 64 hexadecimal digits (one line)."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise SigningKeyError(f"cannot read key file {path}: {exc.strerror}") from None
    if len(data) == KEY_BYTES:
        return data
    text = data.strip()
    if len(text) == 2 * KEY_BYTES:
        try:
            return bytes.fromhex(text.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            pass
    raise SigningKeyError(f"{path}: a key file holds 32 bytes or 64 hex digits, not {len(data)} bytes")


def parse_key(value: str) -> bytes:
    """`--signing-key VALUE`: the key file VALUE names when it exists, else the passphrase VALUE."""
    return key_from_file(value) if Path(value).is_file() else key_from_passphrase(value)


def timestamp_now(now: float | None = None) -> int:
    """The signing timestamp for a UNIX time (now by default)."""
    return max(0, int(((time.time() if now is None else now) - EPOCH_2015) * 1e5))


def signature_of(key: bytes, signed_part: bytes) -> bytes:
    """The 6-byte signature of a packet's bytes up to and including its timestamp."""
    return hashlib.sha256(key + signed_part).digest()[:6]


@dataclass
class SigningCounters:
    """What the check saw. `rejected` / `accepted_unsigned` by reason: "unsigned",
    "bad signature", "old timestamp"; accepted_unsigned only counts when signing is optional."""

    good: int = 0
    rejected: dict[str, int] = field(default_factory=dict)
    accepted_unsigned: dict[str, int] = field(default_factory=dict)
    radio_unsigned: int = 0


@dataclass(frozen=True, slots=True)
class SigningSnapshot:
    required: bool
    link_id: int
    good: int
    rejected: dict[str, int]
    accepted_unsigned: dict[str, int]
    radio_unsigned: int


class Signing:
    """One link's signing: sign what the station sends, check what it receives.

    `check(packet, type)` returns None to accept the packet, or the reason it is refused; with
    `required=False` nothing is refused, the reason is counted as accepted-unsigned instead.
    """

    def __init__(self, key: bytes, *, required: bool = True, link_id: int = 0) -> None:
        if len(key) != KEY_BYTES:
            raise SigningKeyError(f"a signing key is {KEY_BYTES} bytes, not {len(key)}")
        self.key = key
        self.required = required
        self.link_id = link_id & 0xFF
        self.counters = SigningCounters()
        self._streams: dict[tuple[int, int, int], int] = {}  # (link id, sysid, compid) → last timestamp
        self._newest = timestamp_now()
        self._encoders: list[Encoder] = []

    def sign_with(self, encoder: Encoder) -> None:
        """Make `encoder` sign every packet (MAVLink 2 only: signing needs it)."""
        s = encoder.mav.signing
        s.secret_key, s.sign_outgoing, s.link_id = self.key, True, self.link_id
        s.timestamp = max(s.timestamp, timestamp_now())
        encoder.mavlink1 = False
        self._encoders.append(encoder)

    def check(self, packet: bytes, msg_type: str) -> str | None:
        """None when the packet (of type `msg_type`) is accepted; else why it is refused
        (counted either way)."""
        reason = self._verify(packet)
        c = self.counters
        if reason is None:
            return None
        if msg_type in UNSIGNED_ALLOWED and reason == "unsigned":
            c.radio_unsigned += 1
            return None
        if self.required:
            c.rejected[reason] = c.rejected.get(reason, 0) + 1
            return reason
        c.accepted_unsigned[reason] = c.accepted_unsigned.get(reason, 0) + 1
        return None

    def _verify(self, buf: bytes) -> str | None:
        if not buf or buf[0] != MARKER_V2 or not buf[2] & _FLAG_SIGNED or len(buf) < 10 + SIGNATURE_BYTES + 2:
            return "unsigned"
        link_id = buf[-13]
        low, high = struct.unpack("<IH", buf[-12:-6])
        stamp = low | (high << 32)
        if signature_of(self.key, buf[:-6]) != buf[-6:]:
            return "bad signature"
        stream = (link_id, buf[5], buf[6])
        last = self._streams.get(stream)
        if (last is not None and stamp <= last) or (last is None and stamp + NEW_STREAM_SLACK < self._newest):
            return "old timestamp"
        self._streams[stream] = stamp
        self.counters.good += 1
        if stamp > self._newest:  # our own timestamps never fall behind what we receive
            self._newest = stamp
            for encoder in self._encoders:
                encoder.mav.signing.timestamp = max(encoder.mav.signing.timestamp, stamp)
        return None

    def snapshot(self) -> SigningSnapshot:
        c = self.counters
        return SigningSnapshot(
            self.required, self.link_id, c.good, dict(c.rejected), dict(c.accepted_unsigned), c.radio_unsigned
        )


def setup_signing_message(
    key: bytes, target_system: int, target_component: int, initial_timestamp: int | None = None
) -> MAVLinkMessage:
    """SETUP_SIGNING giving the vehicle `key`, as MAVProxy's `signing setup` sends it; the vehicle
    stores it and signs from then on. An all-zero key with `initial_timestamp` 0 switches signing
    off (MAVProxy's `signing remove`); with any other timestamp ArduPilot signs with zeros."""
    stamp = timestamp_now() if initial_timestamp is None else initial_timestamp
    return mavlink.MAVLink_setup_signing_message(target_system, target_component, list(key), stamp)
