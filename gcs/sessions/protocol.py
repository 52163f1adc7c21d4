"""Test protocols on disk and in sessions: the shipped protocol files, the protocol run a session's
event log holds, and its tables (gcs.core.protocol) as CSV rows and .mat variables.

A protocol run is recorded as `protocol` events in events.jsonl (`action`: "start" with the whole
protocol, "hold" with each completed step's window on the vehicle clock, "skip", "end"), so the
tables are recomputed from the session alone, by the same functions the live run used.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import asdict
from importlib import resources
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from gcs.core.protocol import (
    ACCEL_MAG,
    Protocol,
    ProtocolError,
    ProtocolTables,
    Series,
    StepWindow,
    accel_mag_series,
    parse_protocol,
    protocol_from_dict,
    protocol_tables,
)
from gcs.sessions.contents import Contents

#: The event kind of every protocol event.
EVENT_KIND = "protocol"
_SHIPPED = resources.files("gcs.sessions").joinpath("protocol_files")


def available_protocols() -> list[str]:
    """The shipped protocols' names (gcs/sessions/protocol_files/*.toml)."""
    return sorted(p.name.removesuffix(".toml") for p in _SHIPPED.iterdir() if p.name.endswith(".toml"))


def load_protocol(name_or_path: str) -> Protocol:
    """A shipped protocol by name, or a TOML file by path; ProtocolError says what is wrong."""
    if name_or_path in available_protocols():
        return parse_protocol(_SHIPPED.joinpath(f"{name_or_path}.toml").read_text(), name_or_path)
    path = Path(name_or_path)
    if not path.is_file():
        shipped = ", ".join(available_protocols())
        raise ProtocolError(f"no protocol {name_or_path!r}: neither a file nor one of {shipped}")
    try:
        return parse_protocol(path.read_text(), path.stem)
    except ProtocolError as exc:
        raise ProtocolError(f"{path}: {exc}") from None


def window_event(window: StepWindow) -> dict[str, object]:
    """The `hold` event's data for a completed step."""
    return {"action": "hold", **asdict(window)}


def run_from_events(events: Iterable[dict]) -> tuple[Protocol, list[StepWindow]] | None:
    """The last protocol run in a session's events: its protocol and completed step windows."""
    protocol: Protocol | None = None
    windows: list[StepWindow] = []
    for e in events:
        if e.get("kind") != EVENT_KIND:
            continue
        if e.get("action") == "start" and isinstance(e.get("protocol"), dict):
            protocol, windows = protocol_from_dict(e["protocol"]), []
        elif e.get("action") == "hold" and protocol is not None:
            try:
                windows.append(StepWindow(*(e[f] for f in StepWindow.__dataclass_fields__)))
            except KeyError:
                continue  # a damaged line loses that step only
    return None if protocol is None else (protocol, windows)


def session_tables(contents: Contents) -> ProtocolTables | None:
    """The protocol tables of a session (None when it holds no protocol run): every recorded
    source, and the raw accelerometer/magnetometer angles from the session's IMU samples."""
    run = run_from_events(contents.event_list)
    if run is None:
        return None
    protocol, windows = run
    boot = run_boot(contents)
    series = {}
    for source in contents.sources:
        data, boots = contents.boot_series(source)
        series[source] = data[:, :4] if boot is None else data[boots == boot, :4]
    raw = raw_angles(contents, windows, boot)
    if raw is not None:
        series[ACCEL_MAG] = raw
    return protocol_tables(protocol, windows, series)


def run_boot(contents: Contents) -> int | None:
    """The boot of the vehicle (`Contents.row_boots`) the last protocol run ran in, by its start's
    wall time (None: not known, every row is taken). Its windows are on that boot's clock: with
    every boot's rows, a vehicle that rebooted in the session had its run scored with samples of
    another boot at the same clock readings, its rows in boot order searched as if in time order."""
    starts = [e for e in contents.event_list if e.get("kind") == EVENT_KIND and e.get("action") == "start"]
    wall = starts[-1].get("wall_time") if starts else None
    return contents.boot_at(float(wall)) if isinstance(wall, int | float) else None


def raw_angles(contents: Contents, windows: list[StepWindow], boot: int | None = None) -> Series | None:
    """accel_mag_series over the step windows only, from the first IMU's samples (of `boot` alone
    when given), with the declination the estimators used (the last one recorded in the events)."""
    imu = contents.imu
    if not imu.num_rows or not windows:
        return None
    first = pc.equal(imu["source"], imu["source"][0]).to_numpy(zero_copy_only=False)
    if boot is not None:
        first = first & (contents.imu_boots == boot)
    imu = imu.filter(first)
    data = np.column_stack([imu[c].to_numpy(zero_copy_only=False) for c in imu.column_names if c != "source"])
    keep = np.zeros(len(data), dtype=bool)
    for w in windows:
        keep |= (data[:, 0] >= w.t_start) & (data[:, 0] <= w.t_hold_end)
    declinations = [e.get("declination_rad") for e in contents.event_list if e.get("kind") == "declination"]
    known = [d for d in declinations if isinstance(d, int | float)]
    return accel_mag_series(data[keep], known[-1] if known else 0.0)


# --- flat tables: CSV rows and .mat structs -------------------------------------------------------


def table_rows(tables: ProtocolTables) -> list[dict[str, object]]:
    """Every row of the three tables, each with `table` = "steps", "axis_means" or "mse"."""
    rows: list[dict[str, object]] = []
    for name, items in (("steps", tables.steps), ("axis_means", tables.axis_means), ("mse", tables.mse)):
        rows += [{"table": name, **asdict(item)} for item in items]
    return rows


def csv_table(tables: ProtocolTables) -> pa.Table:
    """The three tables in one CSV-ready table (columns a table lacks are empty)."""
    rows = table_rows(tables)
    columns = list(dict.fromkeys(key for row in rows for key in row))
    return pa.Table.from_pylist([{key: row.get(key) for key in columns} for row in rows])


def mat_struct(tables: ProtocolTables) -> dict[str, object]:
    """The `protocol` variable of the .mat export: `name`, and `steps`, `axis_means`, `mse` as
    structs of column vectors (numbers) and cell arrays (text)."""
    out: dict[str, object] = {"name": tables.protocol.name}
    for name, items in (("steps", tables.steps), ("axis_means", tables.axis_means), ("mse", tables.mse)):
        records = [asdict(item) for item in items]
        if not records:
            continue
        struct: dict[str, object] = {}
        for key in records[0]:
            values = [r[key] for r in records]
            if all(isinstance(v, int | float) for v in values):
                struct[key] = np.asarray(values, dtype=np.float64).reshape(-1, 1)
            else:
                cell = np.empty((len(values), 1), dtype=object)
                for k, v in enumerate(values):
                    cell[k, 0] = str(v)
                struct[key] = cell
        out[name] = struct
    return out


def formatted(value: object, digits: int = 3) -> str:
    """A table cell as people read it: numbers rounded, NaN as a dash."""
    if isinstance(value, float):
        return "–" if math.isnan(value) else f"{value:.{digits}f}"
    return str(value)
