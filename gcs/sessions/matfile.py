"""A session as a MATLAB/Octave .mat file (scipy.io.savemat, MAT v5), one struct per source,
as Mission Planner's MAT export gives one variable per message.

Variables (every name a valid MATLAB identifier; see `matlab_name`):

- `<source>` for each source (onboard, ahrs2, truth, dcm, kf, ekf, ...): a struct with column
  vectors `t` (vehicle s), `boot` (which boot of the vehicle, 1 = the first: `t` starts again
  near 0 after a reboot, and plotting `t` alone drew a line back from one boot into the next),
  `wall_time` (UNIX s, NaN where unknown), `roll`, `pitch`, `yaw` (degrees, Z-Y-X). An
  estimator's struct also has `errors`: one field per reference, each a struct with `t`, `boot`,
  `roll`, `pitch`, `yaw` (estimator − reference at the reference's times, degrees, wrapped to
  ±180), `rms` and `max` (1×3: roll, pitch, yaw).
- `gain_changes`: a struct of column vectors, one row per gain change in events.jsonl:
  `wall_time` (UNIX s), `t` (vehicle s, through the session's clock offset; NaN without one),
  `estimator`, `gain`, `client` (cell arrays of char), `old`, `new`.
- `info`: `name`, `kind`, `sources` (cell: source name → its variable name), `units`.
- `protocol`, when the session holds a test protocol run (gcs.sessions.protocol): `name` and the
  structs `steps` (seed 000's figures and seed 004's MSE per source and step), `axis_means` and
  `mse` (seed 004's table with the reduction relative to the raw accelerometer/magnetometer
  angles), one column per field, the same rows as protocol.csv and the HTML report.
"""

from __future__ import annotations

import math
import os
import re

import numpy as np
import scipy.io

from gcs.sessions import layout
from gcs.sessions.contents import Contents
from gcs.sessions.protocol import mat_struct, session_tables

#: MATLAB's namelengthmax.
NAME_MAX = 63
_INVALID = re.compile(r"[^A-Za-z0-9_]")
RESERVED = frozenset({"gain_changes", "info", "protocol"})


def matlab_name(text: str, taken: set[str]) -> str:
    """A valid MATLAB identifier for text (letters, digits, underscores, starting with a letter,
    at most 63 characters), not in `taken` (which it is added to)."""
    name = _INVALID.sub("_", text)
    if not name or not name[0].isalpha():
        name = "x" + name
    name = name[:NAME_MAX]
    base, n = name, 2
    while name in taken:
        suffix = f"_{n}"
        name, n = base[: NAME_MAX - len(suffix)] + suffix, n + 1
    taken.add(name)
    return name


def _column(values) -> np.ndarray:
    return np.asarray(values, dtype=np.float64).reshape(-1, 1)


def _float(value: object) -> float:
    """A number from an event line; NaN for anything else (a missing or damaged field)."""
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else math.nan


def _cell(values: list) -> np.ndarray:
    cell = np.empty((len(values), 1), dtype=object)
    for k, v in enumerate(values):
        cell[k, 0] = "" if v is None else str(v)
    return cell


def mat_variables(contents: Contents) -> dict[str, object]:
    """The variables of the .mat file (dicts become structs)."""
    taken = set(RESERVED)
    variables: dict[str, object] = {}
    names = {source: matlab_name(source, taken) for source in contents.sources}
    references = contents.references()
    for source, var in names.items():
        data, boots = contents.boot_series(source)
        struct: dict[str, object] = {
            "t": _column(data[:, 0]),
            "boot": _column(boots + 1),
            "wall_time": _column(data[:, 4]),
            **{axis: _column(np.degrees(data[:, 1 + k])) for k, axis in enumerate(("roll", "pitch", "yaw"))},
        }
        if source not in references:
            errors: dict[str, object] = {}
            field_names: set[str] = set()
            for ref in references:
                err, err_boots = contents.boot_errors_of(source, ref)
                if not len(err):
                    continue
                errors[matlab_name(ref, field_names)] = {
                    "t": _column(err[:, 0]),
                    "boot": _column(err_boots + 1),
                    **{axis: _column(err[:, 1 + k]) for k, axis in enumerate(("roll", "pitch", "yaw"))},
                    "rms": np.sqrt(np.mean(err[:, 1:] ** 2, axis=0)).reshape(1, 3),
                    "max": np.max(np.abs(err[:, 1:]), axis=0).reshape(1, 3),
                }
            struct["errors"] = errors
        variables[var] = struct
    gains = [e for e in contents.event_list if e.get("kind") == "gain"]
    wall = [_float(e.get("wall_time")) for e in gains]
    variables["gain_changes"] = {
        "wall_time": _column(wall),
        "t": _column([contents.vehicle_time(w) for w in wall]),  # the clock of the boot running then
        "estimator": _cell([e.get("estimator") for e in gains]),
        "gain": _cell([e.get("gain") for e in gains]),
        "client": _cell([e.get("client") for e in gains]),
        "old": _column([_float(e.get("old")) for e in gains]),
        "new": _column([_float(e.get("new")) for e in gains]),
    }
    pairs = np.empty((len(names), 2), dtype=object)
    for k, (source, var) in enumerate(names.items()):
        pairs[k] = (source, var)
    variables["info"] = {
        "name": layout.utf8_text(contents.path.name),
        "kind": contents.kind,
        "sources": pairs,
        "units": "t: vehicle s since boot (boot: which one, 1 = the first; t starts again at each); "
        "wall_time: UNIX s; angles and errors: degrees, Z-Y-X (yaw, pitch, roll)",
    }
    tables = session_tables(contents) if contents.kind == "session" else None
    if tables is not None:
        variables["protocol"] = mat_struct(tables)
    return variables


def write_mat(contents: Contents, out: str | os.PathLike) -> int:
    """Write the .mat file; returns the number of attitude rows written."""
    variables = mat_variables(contents)
    with open(out, "wb") as fh:
        scipy.io.savemat(fh, variables, do_compression=True, oned_as="column")
    return contents.attitude.num_rows
