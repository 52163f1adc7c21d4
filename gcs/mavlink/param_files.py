"""Parameter files in the Mission Planner / MAVProxy `.param` format, and table differences.

One parameter per line, `NAME,VALUE` (Mission Planner) or `NAME VALUE` (MAVProxy, any run of
spaces or tabs); `#` starts a comment, blank lines are ignored. Files are written sorted by name
as `NAME,VALUE` with the shortest value text that reads back as the same float32, so a file
saved from the vehicle and loaded again writes back exactly what was read.

A load never writes what the vehicle keeps for itself (`not_loadable`): ArduPilot's read-only and
volatile parameters (its @ReadOnly / @Volatile metadata: statistics such as STAT_RUNTIME, sensor
ids such as INS_ACC_ID, ground calibration taken at boot) and the counters pymavlink's mavparm
excludes from loads (FORMAT_VERSION, CMD_TOTAL, LOG_LASTFILE...), and the vehicle's own system id
(SYSID_THISMAV, MAV_SYSID on ArduPilot 4.7, PX4's MAV_SYS_ID). A saved full table then loads
back without rewriting a counter or another board's sensor ids, and one vehicle's tuning copied
to another leaves each its own system id (two on one id mix their data on the link).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

from gcs.mavlink.params import ParamError, check_name, format_value, same_value

_SPLIT = re.compile(r"\s*,\s*|\s+")
#: Characters of a bad line quoted in its error: a file that is no .param file (a .bin given by
#: mistake) has "lines" of kilobytes.
QUOTED = 40

#: (names, why a load leaves them alone), first match wins.
_NOT_LOADABLE = (
    (re.compile(r"STAT_[A-Z]+"), "statistics the vehicle keeps (read-only)"),
    (re.compile(r"FORMAT_VERSION|SYSID_SW_MREV|SYSID_SW_TYPE"), "set by the firmware (read-only)"),
    (
        re.compile(r"INS\d?_(ACC|GYR)\d?_ID|COMPASS_DEV_ID\d?|BARO\d_DEVID|ARSPD\d?_DEVID|GPS\d?_CAN_NODEID\d?"),
        "sensor id of the board the file came from (read-only)",
    ),
    (
        re.compile(r"GND_ABS_PRESS\d?|GND_TEMP|BARO\d?_GND_PRESS|BARO_ABS_PRESS\d?|ARSPD\d?_OFFSET"),
        "ground calibration the vehicle takes at boot (volatile)",
    ),
    (
        re.compile(r"CMD_TOTAL|CMD_INDEX|FENCE_TOTAL|RALLY_TOTAL|LOG_LASTFILE|SYS_NUM_RESETS"),
        "counter the vehicle keeps",
    ),
    (
        re.compile(r"SYSID_THISMAV|MAV_SYSID|MAV_SYS_ID"),
        "the vehicle's own system id (another vehicle's file would give two vehicles one; `gcs params set` changes it)",
    ),
)


class ParamFileError(ParamError):
    """A file that is not a parameter file; the message names the file and line."""


def parse(text: str, source: str = "<text>") -> dict[str, float]:
    """NAME → value of every line of a .param text."""
    values: dict[str, float] = {}
    lines: dict[str, int] = {}
    for number, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = _SPLIT.split(line)
        where = f"{source}:{number}"
        if len(parts) != 2:
            shown = repr(line[:QUOTED]) + (f" ... ({len(line)} characters)" if len(line) > QUOTED else "")
            raise ParamFileError(f"{where}: expected NAME,VALUE or NAME VALUE, got {shown}")
        name, text_value = parts
        try:
            check_name(name)
            value = float(text_value)
        except ParamError as exc:
            raise ParamFileError(f"{where}: {exc}") from None
        except ValueError:
            raise ParamFileError(f"{where}: {name}: {text_value!r} is not a number") from None
        if not math.isfinite(value):  # "nan", "inf", 1e999: no vehicle stores one; a load sent it
            raise ParamFileError(f"{where}: {name}: {text_value!r} is not a finite number")
        if name in values:
            raise ParamFileError(f"{where}: {name} already set on line {lines[name]}")
        values[name], lines[name] = value, number
    return values


def not_loadable(name: str) -> str | None:
    """Why a parameter file load must not write `name`, or None when it may."""
    return next((why for pattern, why in _NOT_LOADABLE if pattern.fullmatch(name)), None)


def load(path: str | Path) -> dict[str, float]:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise ParamFileError(f"cannot read {path}: {exc.strerror}") from None
    return parse(text, str(path))


def dumps(values: dict[str, float], comment: str | None = None) -> str:
    head = "".join(f"# {line}\n" for line in comment.splitlines()) if comment else ""
    return head + "".join(f"{name},{format_value(values[name])}\n" for name in sorted(values))


def save(path: str | Path, values: dict[str, float], comment: str | None = None) -> Path:
    path = Path(path)
    path.write_text(dumps(values, comment), encoding="utf-8")
    return path


@dataclass(frozen=True, slots=True)
class Difference:
    """One parameter that differs: a value of None means the side does not have it."""

    name: str
    a: float | None
    b: float | None

    def as_dict(self) -> dict[str, str | float | None]:
        return {"name": self.name, "a": self.a, "b": self.b}


@dataclass(frozen=True, slots=True)
class Skipped:
    """A difference a load leaves alone, and why (the note printed for it)."""

    difference: Difference
    reason: str

    def note(self) -> str:
        d = self.difference
        show = [("-" if v is None else format_value(v)) for v in (d.a, d.b)]
        return f"skipped {d.name} (file {show[0]}, vehicle {show[1]}): {self.reason}"


def split_loadable(changes: list[Difference]) -> tuple[list[Difference], list[Skipped]]:
    """(the changes a load writes, the read-only and volatile ones it skips)."""
    write, skip = [], []
    for change in changes:
        reason = not_loadable(change.name)
        if reason is None:
            write.append(change)
        else:
            skip.append(Skipped(change, reason))
    return write, skip


def diff(a: dict[str, float], b: dict[str, float]) -> list[Difference]:
    """Parameters whose values differ (as float32) or that only one side has, sorted by name."""
    out = []
    for name in sorted(set(a) | set(b)):
        va, vb = a.get(name), b.get(name)
        if va is None or vb is None or not same_value(va, vb):
            out.append(Difference(name, va, vb))
    return out


def format_diff(differences: list[Difference], a_label: str = "a", b_label: str = "b") -> str:
    if not differences:
        return "no differences"
    width = max(16, *(len(d.name) for d in differences))

    def show(v: float | None) -> str:
        return "(missing)" if v is None else format_value(v)

    lines = [f"{'NAME':<{width}}  {a_label:>14}  {b_label:>14}"]
    lines += [f"{d.name:<{width}}  {show(d.a):>14}  {show(d.b):>14}" for d in differences]
    return "\n".join(lines)
