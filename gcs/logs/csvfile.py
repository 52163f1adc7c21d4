"""CSV files (the `gcs estimate` contract) → the sample stream.

Header with at least t,gx,gy,gz,ax,ay,az,mx,my,mz (any order; t in s, gyro rad/s, accel m/s²
specific force, mag in any consistent unit or empty when absent), optional vn,ve,vd GPS velocity
in m/s NED (empty when absent). Any right-handed sensor frame. A GPS sample is emitted on the
rows where the velocity changes (a velocity held between fixes is one fix).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Iterator
from typing import BinaryIO, TypeGuard

import numpy as np

from gcs.core.samples import GpsSample, ImuSample
from gcs.logs.logfile import InputError

CSV_COLUMNS = ("t", "gx", "gy", "gz", "ax", "ay", "az", "mx", "my", "mz")
CSV_GPS_COLUMNS = ("vn", "ve", "vd")


def _number(path: str, line: int, field: str, text: str, required: bool) -> float | None:
    text = text.strip()
    if not text:
        if required:
            raise InputError(f"{path}: line {line}: field {field!r} is empty")
        return None
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"{path}: line {line}: field {field!r}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise InputError(f"{path}: line {line}: field {field!r}: {text!r} is not finite")
    return value


def _all_given(values: tuple[float | None, float | None, float | None]) -> TypeGuard[tuple[float, float, float]]:
    """True when none of the three (optional) fields is empty."""
    return all(x is not None for x in values)


def _lines(path: str, fh: BinaryIO) -> Iterator[str]:
    """fh's lines as text: UTF-8, without the byte-order mark a spreadsheet's "CSV UTF-8" starts
    with; other bytes (a binary file named .csv) are an InputError naming the line."""
    for number, raw in enumerate(fh, start=1):
        try:
            yield raw.decode("utf-8-sig" if number == 1 else "utf-8")
        except UnicodeDecodeError as exc:
            byte = raw[exc.start]
            raise InputError(f"{path}: line {number}: not UTF-8 text (byte {byte:#04x}); is this a CSV?") from None


def _rows(path: str, lines: Iterable[str]) -> Iterator[list[str]]:
    """The CSV rows of lines; what the csv module refuses (a field over its size limit) is an
    InputError naming the line, not a csv.Error traceback."""
    reader = csv.reader(lines)
    while True:
        try:
            row = next(reader)
        except StopIteration:
            return
        except csv.Error as exc:
            raise InputError(f"{path}: line {reader.line_num}: {exc}") from None
        yield row


def read_csv(path: str, imu: int = 0) -> Iterator[ImuSample | GpsSample]:
    """IMU (and GPS velocity) samples from a CSV following the contract in the module docstring;
    a CSV holds one IMU, instance 0."""
    if imu != 0:
        raise InputError(f"{path}: line 1: a CSV holds one IMU (instance 0), not instance {imu}")
    with open(path, "rb") as fh:
        reader = _rows(path, _lines(path, fh))
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise InputError(f"{path}: line 1: empty file, expected header {','.join(CSV_COLUMNS)}") from None
        missing = [c for c in CSV_COLUMNS if c not in header]
        if missing:
            raise InputError(
                f"{path}: line 1: header lacks column(s) {', '.join(missing)}; expected {','.join(CSV_COLUMNS)}"
                f"[,{','.join(CSV_GPS_COLUMNS)}], got {','.join(header)}"
            )
        col = {name: header.index(name) for name in CSV_COLUMNS + CSV_GPS_COLUMNS if name in header}
        has_gps = all(c in col for c in CSV_GPS_COLUMNS)
        last_vel: tuple[float, float, float] | None = None
        for line, row in enumerate(reader, start=2):
            if not row or all(not cell.strip() for cell in row):
                continue
            if len(row) < len(header):
                raise InputError(f"{path}: line {line}: {len(row)} fields, header has {len(header)}")
            v = {
                name: _number(path, line, name, row[i], name not in ("mx", "my", "mz", *CSV_GPS_COLUMNS))
                for name, i in col.items()
            }
            t = v["t"]
            assert t is not None  # a required field: _number raised if it was empty
            mags = (v["mx"], v["my"], v["mz"])
            if any(m is None for m in mags) and not all(m is None for m in mags):
                raise InputError(f"{path}: line {line}: field 'mx'/'my'/'mz': give all three or none")
            mag = None if mags[0] is None else np.array(mags)
            if has_gps:
                vel = (v["vn"], v["ve"], v["vd"])
                if _all_given(vel) and vel != last_vel:
                    last_vel = vel
                    vn, ve, _ = vel
                    yield GpsSample(
                        t, math.nan, math.nan, math.nan, math.hypot(vn, ve), math.atan2(ve, vn), np.array(vel), 3, "csv"
                    )
            yield ImuSample(t, np.array((v["gx"], v["gy"], v["gz"])), np.array((v["ax"], v["ay"], v["az"])), mag, "csv")
