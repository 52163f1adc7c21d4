"""The simulated vehicle's parameter table and the server side of the MAVLink parameter protocol.

PARAM_REQUEST_LIST streams every parameter, paced at `rate_hz` like firmware; PARAM_REQUEST_READ
answers one by name or index; PARAM_SET stores and echoes the stored value in PARAM_VALUE (unknown
names are ignored, as ArduPilot does). ArduPilot sends every value as the float it equals; PX4 sends
integer parameters bytewise (INT32 bytes as the float32 `param_value`; bit patterns of a signalling
NaN cannot survive a Python float, and no real parameter uses them).
Protocol faults, settable at any time, test a ground station's verify and retry logic: `drop` (a seeded
fraction of PARAM_VALUE packets lost) and `clamp` (name → the largest value the vehicle will store).
See docs/vehicles.md.
"""

from __future__ import annotations

import struct
from collections import deque
from collections.abc import Callable

import numpy as np

from gcs.mavlink.dialect import mavlink
from gcs.mavlink.params import decode, encode, float32, param_name
from gcs.sim.param_tables import Row

PARAM_TYPES = {
    "i8": mavlink.MAV_PARAM_TYPE_INT8,
    "i16": mavlink.MAV_PARAM_TYPE_INT16,
    "i32": mavlink.MAV_PARAM_TYPE_INT32,
    "f": mavlink.MAV_PARAM_TYPE_REAL32,
}
#: Inclusive range of each integer type.
_INT_RANGES = {"i8": (-(2**7), 2**7 - 1), "i16": (-(2**15), 2**15 - 1), "i32": (-(2**31), 2**31 - 1)}


class ParamTable:
    """Ordered parameters (index = position) with their MAVLink types and wire encoding."""

    def __init__(self, rows: list[Row], bytewise: bool) -> None:
        self.names = [name for name, _, _ in rows]
        self.kinds = [kind for _, _, kind in rows]
        self.values: list[float] = []
        self.bytewise = bytewise
        self.index = {name: i for i, name in enumerate(self.names)}
        for i, (_, value, _) in enumerate(rows):
            self.values.append(self._coerce(i, value))

    def __len__(self) -> int:
        return len(self.names)

    def __contains__(self, name: str) -> bool:
        return name in self.index

    def __getitem__(self, name: str) -> float:
        return self.values[self.index[name]]

    def __setitem__(self, name: str, value: float) -> None:
        i = self.index[name]
        self.values[i] = self._coerce(i, value)

    def as_dict(self) -> dict[str, float]:
        return dict(zip(self.names, self.values))

    def _coerce(self, i: int, value: float) -> float:
        """The value as the firmware stores it: integers rounded and saturated, floats float32."""
        kind = self.kinds[i]
        if kind == "f":
            return float32(float(value))
        lo, hi = _INT_RANGES[kind]
        return float(min(max(int(round(value)), lo), hi))

    def wire_value(self, i: int) -> float:
        """The `param_value` float sent for parameter i."""
        if self.bytewise:
            return encode(self.names[i], self.values[i], self.param_type(i), bytewise=True)[0]
        return self.values[i]

    def from_wire(self, i: int, wire: float) -> float:
        """Decode a PARAM_SET `param_value` for parameter i."""
        if self.bytewise:
            return float(decode(struct.pack("<f", wire), self.param_type(i), bytewise=True))
        return wire

    def param_type(self, i: int) -> int:
        return PARAM_TYPES[self.kinds[i]]


class ParamServer:
    """Answers parameter-protocol messages for one table.

    `handle(msg)` returns the replies due now; a list request queues the whole table, which
    `next_due` / `take_due(now)` release at `rate_hz`. `on_change(name, value)` is called after a
    stored value changes (the vehicle applies AHRS gains etc.).
    """

    def __init__(
        self,
        table: ParamTable,
        rng: np.random.Generator,
        drop: float = 0.0,
        clamp: dict[str, float] | None = None,
        rate_hz: float = 250.0,
        on_change: Callable[[str, float], None] | None = None,
    ) -> None:
        self.table = table
        self.rng = rng
        self.drop = drop
        self.clamp: dict[str, float] = dict(clamp or {})
        self.rate_hz = rate_hz
        self.on_change = on_change
        self.dropped = 0
        self._queue: deque[int] = deque()
        self.next_due: float | None = None

    def _value_msg(self, i: int) -> list:
        """PARAM_VALUE for index i, or nothing when the drop fault eats it."""
        if self.drop > 0 and self.rng.random() < self.drop:
            self.dropped += 1
            return []
        t = self.table
        return [mavlink.MAVLink_param_value_message(t.names[i].encode(), t.wire_value(i), t.param_type(i), len(t), i)]

    def handle(self, msg, now: float) -> list:
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_LIST":
            self._queue = deque(range(len(self.table)))
            self.next_due = now
            return []
        if kind == "PARAM_REQUEST_READ":
            i = self._lookup(param_name(msg), msg.param_index)
            return [] if i is None else self._value_msg(i)
        if kind == "PARAM_SET":
            i = self._lookup(param_name(msg), -1)
            if i is None:
                return []
            name = self.table.names[i]
            value = self.table.from_wire(i, msg.param_value)
            if name in self.clamp:
                value = min(value, self.clamp[name])
            old = self.table.values[i]
            self.table[name] = value
            if self.on_change and self.table.values[i] != old:
                self.on_change(name, self.table.values[i])
            return self._value_msg(i)
        return []

    def take_due(self, now: float) -> list:
        """PARAM_VALUE messages of a list download whose send time has come."""
        out = []
        while self._queue and self.next_due is not None and self.next_due <= now:
            out += self._value_msg(self._queue.popleft())
            self.next_due += 1.0 / self.rate_hz
        if not self._queue:
            self.next_due = None
        return out

    def _lookup(self, param_id: str, index: int) -> int | None:
        """Index of a parameter by name, or by index when that is >= 0."""
        if index is not None and index >= 0:
            return index if index < len(self.table) else None
        return self.table.index.get(param_id)
