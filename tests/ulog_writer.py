"""Writes minimal PX4 ULog files for tests (pyulog reads ULog but cannot write it).

The format (docs.px4.io, "ULog File Format"), little-endian throughout: a 16-byte header (the
magic "ULog" 01 12 35, version 1, start time in µs), then messages, each a uint16 payload size, a
type byte and the payload. Definitions come first: 'B' flag bits (8 compat + 8 incompat bytes
and three uint64 appended-data offsets), one 'F' format per topic ("name:type field;..."); then
the data section: 'A' subscribes a topic (uint8 multi_id, uint16 msg_id, name) and 'D' carries
one sample (uint16 msg_id, the fields packed in declared order, no padding). 'P' is a parameter
(uint8 key length, key "float NAME", the value): in the definitions an initial value, in the data
section a change at the time of the sample before it.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

MAGIC = b"ULog\x01\x12\x35"
#: ULog type → struct code.
CODES = {
    "uint64_t": "Q", "int64_t": "q", "uint32_t": "I", "int32_t": "i", "uint16_t": "H", "int16_t": "h",
    "uint8_t": "B", "int8_t": "b", "bool": "?", "float": "f", "double": "d",
}  # fmt: skip


@dataclass
class Topic:
    name: str
    fields: list[tuple[str, str, int]]  # (type, name, array length; 0 for a scalar)
    msg_id: int
    packer: struct.Struct


@dataclass
class UlogWriter:
    """Declare topics with `topic`, then `add` samples in time order; `bytes()` is the file."""

    topics: dict[str, Topic] = field(default_factory=dict)
    data: list[bytes] = field(default_factory=list)
    parameters: list[bytes] = field(default_factory=list)

    def topic(self, name: str, spec: str, multi_id: int = 0) -> None:
        """spec: "uint64_t timestamp;float[3] gyro_rad;...", as in an 'F' message."""
        fields = []
        for item in filter(None, spec.split(";")):
            kind, fname = item.split(" ")
            base, _, count = kind.partition("[")
            fields.append((base, fname, int(count.rstrip("]")) if count else 0))
        packer = struct.Struct("<" + "".join(f"{n or ''}{CODES[t]}" for t, _, n in fields))
        topic = Topic(name, fields, len(self.topics), packer)
        self.topics[name] = topic
        self.data.append(_message(b"A", struct.pack("<BH", multi_id, topic.msg_id) + name.encode()))

    def add(self, name: str, **values: object) -> None:
        topic = self.topics[name]
        flat: list[object] = []
        for _, fname, count in topic.fields:
            value = values[fname]
            flat.extend(value if count else [value])  # type: ignore[call-overload]
        self.data.append(_message(b"D", struct.pack("<H", topic.msg_id) + topic.packer.pack(*flat)))

    def param(self, name: str, value: float) -> None:
        """A float parameter: initial before the first `add`, else a change at that point."""
        key = f"float {name}".encode()
        message = _message(b"P", struct.pack("<B", len(key)) + key + struct.pack("<f", value))
        (self.data if any(m[2:3] == b"D" for m in self.data) else self.parameters).append(message)

    def bytes(self) -> bytes:
        header = MAGIC + b"\x01" + struct.pack("<Q", 0)
        flags = _message(b"B", bytes(16) + bytes(24))
        formats = [
            _message(b"F", f"{t.name}:{';'.join(_decl(f) for f in t.fields)};".encode()) for t in self.topics.values()
        ]
        return header + flags + b"".join(formats) + b"".join(self.parameters) + b"".join(self.data)


def _decl(item: tuple[str, str, int]) -> str:
    kind, name, count = item
    return f"{kind}[{count}] {name}" if count else f"{kind} {name}"


def _message(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<H", len(payload)) + kind + payload
