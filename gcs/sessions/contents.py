"""Everything a session (or a log run through the estimators) holds, as tables: what the MAT and
MCAP exports write and what the notebook API (gcs.api) hands out.

- `attitude`: every source's attitude (columnar.ATTITUDE_SCHEMA, radians): the session's own
  table, or for a .tlog/.bin/.ulg the references it carries and every estimator run over it.
- `comparison`: the session's comparison snapshots (columnar.COMPARISON_SCHEMA); empty for a log.
- `events`: the session's events.jsonl as rows (EVENTS_SCHEMA); empty for a log.
- `imu`: the raw IMU samples the estimators were fed (IMU_SCHEMA), decoded from the session's
  tlog (or the log) by the replay source's InputTable.
- `errors()`: whole-run RMS / max error of each estimator against each reference, from `attitude`.

Two clocks (docs/design.md, "Time"): `t` is the vehicle clock (s since boot), `wall_time` the
host's UNIX time. Events and comparison rows have only the wall clock; `clock_offset()` is the
median wall_time − t of the attitude rows, which places them on the vehicle clock.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.compute as pc

from gcs.core.comparison import errors_against
from gcs.core.estimators import registry
from gcs.core.estimators.whole import InputKind as Kind
from gcs.core.samples import REBOOT_CLOCK_JUMP
from gcs.sessions import columnar, layout
from gcs.sessions.sources import ReplaySource, open_source

EVENTS_SCHEMA = pa.schema(
    [
        ("wall_time", pa.float64()),  # host UNIX time, s
        ("kind", pa.string()),  # "gain", "param", "link", "note", "recording", ...
        ("client", pa.string()),  # who caused it
        ("estimator", pa.string()),  # gain changes: estimator, gain name, old and new value
        ("gain", pa.string()),
        ("old", pa.float64()),
        ("new", pa.float64()),
        ("text", pa.string()),  # notes
        ("data", pa.string()),  # the whole event as its JSON line
    ]
)

IMU_SCHEMA = pa.schema(
    [
        ("t", pa.float64()),  # vehicle time, s
        ("source", pa.string()),  # which IMU (message type or log instance)
        *((f"gyro_{a}", pa.float64()) for a in "xyz"),  # rad/s, body FRD
        *((f"accel_{a}", pa.float64()) for a in "xyz"),  # m/s²
        *((f"mag_{a}", pa.float64()) for a in "xyz"),  # gauss; NaN without a magnetometer
    ]
)

ERRORS_SCHEMA = pa.schema(
    [
        ("estimator", pa.string()),
        ("reference", pa.string()),
        ("n", pa.int64()),  # reference samples scored
        *((f"rms_{a}", pa.float64()) for a in ("roll", "pitch", "yaw")),  # degrees
        *((f"max_{a}", pa.float64()) for a in ("roll", "pitch", "yaw")),
    ]
)

Decode = Callable[[str | os.PathLike], ReplaySource]


def read_events(folder: Path) -> list[dict]:
    """A session's events.jsonl, one dict per line; an incomplete last line (a crash mid-write)
    or a damaged one is skipped. A byte that is not UTF-8 (a flipped bit) is U+FFFD: one damaged
    line, not a file that cannot be read."""
    path = layout.session_file(folder, layout.EVENTS)
    if not path.exists():
        return []
    events = []
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        try:
            event = json.loads(line)
        except ValueError:
            continue
        if isinstance(event, dict):
            events.append(event)
    return events


def _number(value: object) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def events_table(events: list[dict]) -> pa.Table:
    rows = [
        {
            "wall_time": _number(e.get("wall_time")),
            "kind": str(e.get("kind", "")),
            "client": None if e.get("client") is None else str(e["client"]),
            "estimator": e.get("estimator") if e.get("kind") == "gain" else None,
            "gain": e.get("gain") if e.get("kind") == "gain" else None,
            "old": _number(e.get("old")) if e.get("kind") == "gain" else None,
            "new": _number(e.get("new")) if e.get("kind") == "gain" else None,
            "text": None if e.get("text") is None else str(e["text"]),
            "data": json.dumps(e, default=str),
        }
        for e in events
    ]
    return pa.Table.from_pylist(rows, schema=EVENTS_SCHEMA)


def replayed_attitude(source: ReplaySource) -> pa.Table:
    """Every estimator run over the source, with its references, as the attitude table. Each row's
    wall time is that of the tlog record its input came in (a live session's rows carry the time
    they were made, a few ms later); NaN for a .bin or .ulg, which have no host clock."""
    rows: list[tuple] = []
    wall_times = source.input_wall_times().tolist()
    for index, points in source.outputs(source.new_pipeline()):
        rows.extend(columnar.attitude_rows(points, wall_times[index]))
    columns: list[tuple] = list(zip(*rows)) if rows else [() for _ in columnar.ATTITUDE_SCHEMA]
    return pa.table(
        [pa.array(c, type=f.type) for c, f in zip(columns, columnar.ATTITUDE_SCHEMA)], schema=columnar.ATTITUDE_SCHEMA
    )


def imu_table(source: ReplaySource) -> pa.Table:
    imu = source.table.imu
    names = np.array(source.table.names, dtype=object)
    columns: dict[str, object] = {
        "t": imu[:, 0],
        "source": pa.array(names[source.table.imu_source.astype(np.int64)].tolist() if len(imu) else [], pa.string()),
    }
    for k, name in enumerate(IMU_SCHEMA.names[2:]):
        columns[name] = imu[:, 1 + k]
    return pa.table(columns, schema=IMU_SCHEMA)


@dataclass
class Contents:
    """What one session or log holds; tables are built on first use and kept."""

    path: Path
    kind: str  # "session", "tlog", "dataflash", "ulog"
    decode: Decode = field(default=open_source, repr=False)

    @cached_property
    def source(self) -> ReplaySource:
        """The decoded source (the session's tlog, or the log): inputs, references, config."""
        return self.decode(self.path)

    @cached_property
    def attitude(self) -> pa.Table:
        """A session's recorded attitudes; a log's computed from its inputs, and a session's too
        where its attitude table is gone (a copy without it): its tlog replayed gives the numbers
        it recorded, where 0 rows were exported."""
        if self.kind == "session" and columnar.has_table(self.path, "attitude"):
            return columnar.read_table(self.path, "attitude")
        return replayed_attitude(self.source)

    @cached_property
    def comparison(self) -> pa.Table:
        if self.kind == "session":
            return columnar.read_table(self.path, "comparison")
        return columnar.COMPARISON_SCHEMA.empty_table()

    @cached_property
    def event_list(self) -> list[dict]:
        return read_events(self.path) if self.kind == "session" else []

    @cached_property
    def events(self) -> pa.Table:
        return events_table(self.event_list)

    @cached_property
    def imu(self) -> pa.Table:
        return imu_table(self.source)

    @cached_property
    def sources(self) -> list[str]:
        """Source names in the attitude table, references first, then estimators (sorted)."""
        names = set(pc.unique(self.attitude["source"]).to_pylist())
        estimators = set(registry.names())
        return sorted(names - estimators) + sorted(names & estimators)

    def estimators(self) -> list[str]:
        return [s for s in self.sources if s in registry.names()]

    def references(self) -> list[str]:
        return [s for s in self.sources if s not in registry.names()]

    def series(self, source: str) -> npt.NDArray[np.float64]:
        """N×5 array of one source: t (vehicle s), roll, pitch, yaw (rad), wall_time (UNIX s or NaN),
        in time order within each boot of the vehicle, the boots in the order recorded (`boot_series`)."""
        return self.boot_series(source)[0]

    @cached_property
    def row_boots(self) -> npt.NDArray[np.int64]:
        """Per attitude row, which boot of the vehicle it belongs to (`boot_numbers` of every
        source's rows together, in the order recorded): a boot has one number in every source,
        one that has no row in some boot (a reference that starts after a reboot) included."""
        return boot_numbers(self.attitude["t"].to_numpy(zero_copy_only=False))

    def boot_series(self, source: str) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
        """`series(source)` and the boot number of each of its rows (`row_boots`)."""
        rows = pc.equal(self.attitude["source"], source).to_numpy(zero_copy_only=False)
        table = self.attitude.filter(rows)
        data = np.column_stack(
            [table[c].to_numpy(zero_copy_only=False) for c in ("t", "roll", "pitch", "yaw", "wall_time")]
        ).reshape(-1, 5)
        return in_boot_order(data, self.row_boots[rows])

    def errors_of(self, estimator: str, reference: str) -> npt.NDArray[np.float64]:
        """M×4: estimator − reference at the reference's times (t s, roll, pitch, yaw error deg),
        each boot against the same boot: sorted by time alone, a session whose vehicle rebooted
        (a serial port that came back with the vehicle restarted) scored one boot's estimates
        against the other's references, as the live comparison never does."""
        return self.boot_errors_of(estimator, reference)[0]

    def boot_errors_of(self, estimator: str, reference: str) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
        """`errors_of` and the boot (`row_boots`) of each of its rows."""
        estimates, estimate_boots = self.boot_series(estimator)
        references, reference_boots = self.boot_series(reference)
        return errors_by_boot(estimates[:, :4], estimate_boots, references[:, :4], reference_boots)

    def errors(self) -> pa.Table:
        """Whole-run RMS and max |error| (degrees) of every estimator against every reference."""
        rows = []
        for est in self.estimators():
            for ref in self.references():
                err = self.errors_of(est, ref)[:, 1:]
                if not len(err):
                    continue
                rms, worst = np.sqrt(np.mean(err**2, axis=0)), np.max(np.abs(err), axis=0)
                rows.append(
                    {
                        "estimator": est,
                        "reference": ref,
                        "n": len(err),
                        **{f"rms_{a}": float(v) for a, v in zip(("roll", "pitch", "yaw"), rms)},
                        **{f"max_{a}": float(v) for a, v in zip(("roll", "pitch", "yaw"), worst)},
                    }
                )
        return pa.Table.from_pylist(rows, schema=ERRORS_SCHEMA)

    def clock_offset(self) -> float | None:
        """Median wall_time − t over the attitude rows that have both clocks (UNIX s at vehicle
        t = 0), or None when there is no wall time (logs)."""
        diff = pc.subtract(self.attitude["wall_time"], self.attitude["t"]).to_numpy(zero_copy_only=False)
        diff = diff[np.isfinite(diff)]
        return float(np.median(diff)) if len(diff) else None

    @cached_property
    def boot_clocks(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.int64]]:
        """Per boot of the vehicle that has wall time: the UNIX time (s) of its first attitude row,
        its clock offset (median wall_time − t) and its number (`row_boots`), in the order
        recorded; empty for logs."""
        t = self.attitude["t"].to_numpy(zero_copy_only=False)
        wall = self.attitude["wall_time"].to_numpy(zero_copy_only=False)
        boot = self.row_boots
        starts, offsets, numbers = [], [], []
        for number in np.unique(boot).tolist():
            rows = (boot == number) & np.isfinite(wall)
            if rows.any():
                starts.append(float(wall[rows].min()))
                offsets.append(float(np.median(wall[rows] - t[rows])))
                numbers.append(number)
        return np.array(starts), np.array(offsets), np.array(numbers, dtype=np.int64)

    def _boot_at(self, wall: float) -> int:
        """The index in `boot_clocks` of the boot running at host UNIX time `wall` (before the
        first boot: the first); there is one."""
        starts = self.boot_clocks[0]
        return max(0, int(np.searchsorted(starts, wall, side="right")) - 1)

    def boot_at(self, wall: float) -> int | None:
        """The number (`row_boots`) of the boot running at host UNIX time `wall` (before the first
        boot: the first); None for a log, which has no host clock."""
        numbers = self.boot_clocks[2]
        return int(numbers[self._boot_at(wall)]) if len(numbers) else None

    def vehicle_time(self, wall: float) -> float:
        """A host UNIX time (s; an event's, a comparison row's) on the vehicle clock, by the offset
        of the boot running then (before the first boot: the first boot's): one offset for a whole
        session whose vehicle rebooted placed one boot's events a boot's length off. NaN for a log."""
        if not len(self.boot_clocks[0]):
            return math.nan
        return wall - float(self.boot_clocks[1][self._boot_at(wall)])

    @cached_property
    def boot_shifts(self) -> npt.NDArray[np.float64]:
        """Per boot (`row_boots`), the s added to its vehicle times to lay it BOOT_GAP_S after the
        end of the boot before it: one timeline for a file whose readers order everything by time
        (MCAP's log_time), where each reboot's clock from 0 laid the boots over each other."""
        t = self.attitude["t"].to_numpy(zero_copy_only=False)
        boot = self.row_boots
        shifts = [0.0]
        for number in range(1, int(boot.max()) + 1 if len(boot) else 0):
            end, start = np.nanmax(t[boot == number - 1]), np.nanmin(t[boot == number])
            shifts.append(shifts[-1] + float(end) + BOOT_GAP_S - float(start))
        return np.array(shifts)

    def timeline(self, wall: float) -> float:
        """`vehicle_time(wall)` on the one timeline of `boot_shifts` (NaN for a log)."""
        if not len(self.boot_clocks[0]):
            return math.nan
        at = self._boot_at(wall)
        return self.vehicle_time(wall) + float(self.boot_shifts[self.boot_clocks[2][at]])

    @cached_property
    def imu_boots(self) -> npt.NDArray[np.int64]:
        """Per row of `source.table.imu`, its boot (`row_boots`' numbers): `boot_numbers` over the
        IMU and reference inputs in the order they arrived, which every boot with an attitude row has."""
        table = self.source.table
        imu = (table.kind == Kind.IMU) | (table.kind == Kind.IMU_MAG)
        timed = imu | (table.kind == Kind.ATTITUDE)
        t = np.empty(len(table.kind))
        t[imu], t[table.kind == Kind.ATTITUDE] = table.imu[:, 0], table.attitude[:, 0]
        boots = np.zeros(len(t), np.int64)
        boots[timed] = boot_numbers(t[timed])
        return np.minimum(boots[imu], len(self.boot_shifts) - 1)


#: s between the end of one boot and the start of the next on the exports' one timeline.
BOOT_GAP_S = 1.0


def boot_numbers(t: npt.NDArray[np.float64]) -> npt.NDArray[np.int64]:
    """Per row in the order recorded (of one source, or of every source together), which boot of
    the vehicle it belongs to: a row more than REBOOT_CLOCK_JUMP behind the newest of its boot
    starts the next one, the rule by which the live comparison starts afresh (one row a little
    behind another source's is no reboot; the newest, not the row before, is the boot's clock)."""
    numbers = np.zeros(len(t), np.int64)
    start = 0
    while start < len(t):
        rest = t[start:]
        back = np.flatnonzero(rest < np.maximum.accumulate(rest) - REBOOT_CLOCK_JUMP)
        if not len(back):
            break
        start += int(back[0])
        numbers[start:] += 1
    return numbers


class BootCounter:
    """`boot_numbers` a row at a time, for rows that come one by one (a replay's points)."""

    def __init__(self) -> None:
        self.newest = -math.inf
        self.boot = 0

    def of(self, t: float) -> int:
        """The boot of a row at vehicle time t, the rows taken in the order recorded."""
        if t < self.newest - REBOOT_CLOCK_JUMP:
            self.boot += 1
            self.newest = t
        elif t > self.newest:
            self.newest = t
        return self.boot


def in_boot_order(
    rows: npt.NDArray[np.float64], boots: npt.NDArray[np.int64]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Rows (t first) and their boot numbers, sorted by boot and, within a boot, by time."""
    order = np.lexsort((rows[:, 0], boots))
    return rows[order], boots[order]


def errors_by_boot(
    estimates: npt.NDArray[np.float64],
    estimate_boots: npt.NDArray[np.int64],
    reference: npt.NDArray[np.float64],
    reference_boots: npt.NDArray[np.int64],
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """`errors_against` of each boot of the reference against the estimator's same boot (both N×4
    t, roll, pitch, yaw rad, each boot in time order; `*_boots`: each row's boot number, the same
    for both sources, `Contents.row_boots`). The vehicle clock starts again at 0 at a reboot, so
    one search across boots matched one boot's estimates with another's references; pairing the
    boots by their position in each source did too where a source has no row in some boot.
    Returns the M×4 errors and the boot of each."""
    numbers = np.unique(reference_boots)
    parts = [
        errors_against(estimates[estimate_boots == boot], reference[reference_boots == boot])
        for boot in numbers.tolist()
    ]
    if not parts:
        return np.empty((0, 4)), np.empty(0, np.int64)
    return np.concatenate(parts), np.repeat(numbers, [len(part) for part in parts])


def open_contents(path: str | os.PathLike, decode: Decode = open_source) -> Contents:
    """The contents of a session folder, .tlog, .bin or .ulg; InputError names what is wrong."""
    folder = Path(path)
    if layout.is_session(folder):
        return Contents(folder, "session", decode)
    source = decode(path)  # raises InputError for anything that is not a readable log
    contents = Contents(Path(path), source.kind, decode)
    contents.__dict__["source"] = source  # fill the cached property: decoded once
    return contents
