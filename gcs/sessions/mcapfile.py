"""A session as an MCAP file that Foxglove Studio and PlotJuggler open directly (no bridge).

Every channel is JSON (`message_encoding="json"`) with a JSON Schema (`encoding="jsonschema"`,
an object schema, as Foxglove requires). Topics:

| topic | schema | one message per |
|---|---|---|
| `/attitude/<source>` | `gcs.Attitude` | attitude row of that source (t, wall_time, roll/pitch/yaw deg) |
| `/imu/<imu>` | `gcs.Imu` | raw IMU sample fed to the estimators (gyro rad/s, accel m/s², mag gauss) |
| `/comparison/<estimator>/<reference>` | `gcs.Comparison` | comparison snapshot row (RMS / max deg) |
| `/events` | `foxglove.Log` | line of events.jsonl (the Log panel shows them; `event` holds the line) |

Clocks. `log_time` is on the vehicle clock (ns since boot) for everything, so the file has one
timeline: attitude and IMU use their vehicle time `t`; comparison rows and events, which have only
the host's wall clock, are placed on it with the clock offset of the boot running then (median
wall_time − t of its attitude rows), and fall back to the wall time itself when there is no offset.
After a reboot (the vehicle clock from 0 again) each boot is laid BOOT_GAP_S after the one before
(`Contents.boot_shifts`): on its own clock the second boot lay over the first, and a reader,
which orders by log_time, drew the two boots' samples interleaved in one zigzag line. `publish_time`
is the host wall time (UNIX ns) where one is known, else equal to `log_time`; every message also
carries its raw times as fields. A `gcs` metadata record says so in the file.

Non-finite numbers (NaN: a missing magnetometer, no wall time) are written as JSON null.
"""

from __future__ import annotations

import heapq
import json
import math
import os
from collections.abc import Iterator
from typing import Any

import numpy as np
import pyarrow.compute as pc
from mcap.writer import Writer

from gcs.sessions import layout
from gcs.sessions.contents import BOOT_GAP_S, Contents

NUMBER = {"type": "number"}
OPTIONAL_NUMBER = {"type": ["number", "null"]}


def _vector(unit: str, optional: bool = False) -> dict:
    schema = {
        "type": "object",
        "description": unit,
        "properties": {a: NUMBER for a in "xyz"},
        "required": ["x", "y", "z"],
    }
    return {"oneOf": [schema, {"type": "null"}]} if optional else schema


def _object(title: str, properties: dict[str, Any], required: list[str] | None = None) -> dict:
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "type": "object",
        "properties": properties,
        "required": list(properties) if required is None else required,
    }


ATTITUDE = _object(
    "gcs.Attitude",
    {
        "t": {**NUMBER, "description": "vehicle time, s since boot"},
        "wall_time": {**OPTIONAL_NUMBER, "description": "host UNIX time the point was produced, s"},
        "roll_deg": NUMBER,
        "pitch_deg": NUMBER,
        "yaw_deg": NUMBER,
    },
)
IMU = _object(
    "gcs.Imu",
    {
        "t": {**NUMBER, "description": "vehicle time, s since boot"},
        "gyro": _vector("rad/s, body FRD"),
        "accel": _vector("m/s², body FRD"),
        "mag": _vector("gauss, body FRD; null without a magnetometer", optional=True),
    },
)
COMPARISON = _object(
    "gcs.Comparison",
    {
        "wall_time": {**NUMBER, "description": "host UNIX time of the snapshot, s"},
        "estimator": {"type": "string"},
        "reference": {"type": "string"},
        "n": {"type": "integer"},
        **{f"{stat}_{axis}": OPTIONAL_NUMBER for stat in ("rms", "max") for axis in ("roll", "pitch", "yaw")},
        "lag_s": OPTIONAL_NUMBER,
        "imu_rate_hz": OPTIONAL_NUMBER,
    },
)
TIME = {
    "type": "object",
    "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0}},
    "required": ["sec", "nsec"],
}
LOG = _object(
    "foxglove.Log",
    {
        "timestamp": {**TIME, "description": "host wall time of the event"},
        "level": {"type": "integer", "description": "2 = INFO"},
        "message": {"type": "string"},
        "name": {"type": "string"},
        "file": {"type": "string"},
        "line": {"type": "integer", "minimum": 0},
        "event": {"type": "object", "description": "the events.jsonl line"},
    },
)
INFO = 2

#: (log_time ns, publish_time ns, channel id, JSON bytes)
Message = tuple[int, int, int, bytes]


def _finite(value: Any) -> Any:
    return value if not isinstance(value, float) or math.isfinite(value) else None


#: The latest time an MCAP record holds (uint64 ns, the year 2554).
MAX_NS = 2**64 - 1


def _ns(seconds: float) -> int:
    """seconds as MCAP's uint64 ns, clamped into its range: a tlog record's damaged timestamp (one
    flipped bit: 2285 years ahead) stopped the export with struct.error; the message is written,
    its own wall_time field keeps the value."""
    return min(MAX_NS, max(0, round(seconds * 1e9)))


def _xyz(row: np.ndarray, start: int) -> dict[str, float]:
    return {"x": float(row[start]), "y": float(row[start + 1]), "z": float(row[start + 2])}


class McapExport:
    def __init__(self, contents: Contents) -> None:
        self.contents = contents
        self.offset = contents.clock_offset()

    def _on_vehicle_clock(self, wall: float) -> float:
        """By the clock offset of the boot running then, on the one timeline (Contents.timeline)."""
        return wall if self.offset is None else self.contents.timeline(wall)

    def attitude(self, channel: int, source: str) -> Iterator[Message]:
        rows, boots = self.contents.boot_series(source)
        shifts = self.contents.boot_shifts[boots].tolist()
        for (t, roll, pitch, yaw, wall), shift in zip(rows.tolist(), shifts, strict=True):
            log = _ns(t + shift)
            data = {
                "t": t,
                "wall_time": _finite(wall),
                "roll_deg": math.degrees(roll),
                "pitch_deg": math.degrees(pitch),
                "yaw_deg": math.degrees(yaw),
            }
            yield log, _ns(wall) if math.isfinite(wall) else log, channel, json.dumps(data).encode()

    def imu(self, channel: int, rows: np.ndarray, boots: np.ndarray) -> Iterator[Message]:
        """IMU rows (of one IMU) and their boots, in time order within each boot."""
        order = np.lexsort((rows[:, 0], boots))
        for row, shift in zip(rows[order], self.contents.boot_shifts[boots[order]].tolist(), strict=True):
            mag = None if np.isnan(row[7:10]).any() else _xyz(row, 7)
            data = {"t": float(row[0]), "gyro": _xyz(row, 1), "accel": _xyz(row, 4), "mag": mag}
            log = _ns(float(row[0]) + shift)
            yield log, log, channel, json.dumps(data).encode()

    def comparison(self, channel: int, rows: list[dict]) -> Iterator[Message]:
        for row in rows:
            wall = row["wall_time"]
            yield (
                _ns(self._on_vehicle_clock(wall)),
                _ns(wall),
                channel,
                json.dumps({k: _finite(v) for k, v in row.items()}).encode(),
            )

    def events(self, channel: int) -> Iterator[Message]:
        # in wall-time order: a line can be written after a later one (events held until the session opened)
        for event in sorted(self.contents.event_list, key=lambda e: float(e.get("wall_time") or 0.0)):
            wall = float(event.get("wall_time") or 0.0)
            details = {k: v for k, v in event.items() if k not in ("wall_time", "host_time", "kind", "client")}
            message = f"{event.get('kind', '?')} ({event.get('client', '?')}): " + ", ".join(
                f"{k}={v}" for k, v in details.items()
            )
            stamp = _ns(wall)
            data = {
                "timestamp": {"sec": stamp // 1_000_000_000, "nsec": stamp % 1_000_000_000},
                "level": INFO,
                "message": message,
                "name": f"gcs/{event.get('kind', '?')}",
                "file": "",
                "line": 0,
                "event": event,
            }
            yield _ns(self._on_vehicle_clock(wall)), stamp, channel, json.dumps(data, default=str).encode()

    def write(self, out: str | os.PathLike) -> dict[str, int]:
        """Write the file; returns messages per topic."""
        contents = self.contents
        with open(out, "wb") as fh:
            writer = Writer(fh)
            writer.start(profile="", library="gcs")
            schemas = {
                s["title"]: writer.register_schema(s["title"], "jsonschema", json.dumps(s).encode())
                for s in (ATTITUDE, IMU, COMPARISON, LOG)
            }
            streams: list[Iterator[Message]] = []
            counts: dict[str, int] = {}

            def channel(topic: str, schema: str, count: int) -> int:
                counts[topic] = count
                return writer.register_channel(topic, "json", schemas[schema])

            for source in contents.sources:
                n = int(pc.sum(pc.equal(contents.attitude["source"], source)).as_py() or 0)
                streams.append(self.attitude(channel(f"/attitude/{source}", "gcs.Attitude", n), source))
            imu = contents.source.table
            for code in np.unique(imu.imu_source).tolist():
                mine = imu.imu_source == code
                rows = imu.imu[mine]
                topic = f"/imu/{imu.names[code]}"
                streams.append(self.imu(channel(topic, "gcs.Imu", len(rows)), rows, contents.imu_boots[mine]))
            comparison = contents.comparison.to_pylist()
            pairs: dict[tuple[str, str], list[dict]] = {}
            for row in comparison:
                pairs.setdefault((row["estimator"], row["reference"]), []).append(row)
            for (est, ref), rows_of_pair in sorted(pairs.items()):
                topic = f"/comparison/{est}/{ref}"
                streams.append(self.comparison(channel(topic, "gcs.Comparison", len(rows_of_pair)), rows_of_pair))
            streams.append(self.events(channel("/events", "foxglove.Log", len(contents.event_list))))
            writer.add_metadata(
                "gcs",
                {
                    "session": layout.utf8_text(contents.path.name),
                    "kind": contents.kind,
                    "log_time": "vehicle clock, ns since boot; wall-clock-only records (comparison, events) "
                    "are placed on it with clock_offset_s (after a reboot, with that boot's own offset); "
                    f"after a reboot each boot follows the one before, {BOOT_GAP_S:g} s after its end "
                    "(its messages' t: their own clock)",
                    "publish_time": "host UNIX time, ns, where known; else log_time",
                    "clock_offset_s": "" if self.offset is None else repr(self.offset),
                    "angles": "degrees, Z-Y-X; IMU in SI (rad/s, m/s²) and gauss, body FRD",
                },
            )
            for sequence, (log, publish, chan, data) in enumerate(heapq.merge(*streams, key=lambda m: m[0])):
                writer.add_message(chan, log_time=log, data=data, publish_time=publish, sequence=sequence)
            writer.finish()
        return counts


def write_mcap(contents: Contents, out: str | os.PathLike) -> int:
    """Write the MCAP file; returns the number of messages."""
    return sum(McapExport(contents).write(out).values())
