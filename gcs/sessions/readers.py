"""Log readers: every input format becomes one time-ordered stream of samples
(`ImuSample`, `GpsSample`, `AttitudeSample`) on the vehicle clock, in arrival order.

`read_samples(path)` picks the reader by file suffix from `READERS`; a reader is a function
path → iterator of samples, so .bin and .ulg readers slot in beside these. Bad input raises
`InputError` naming the file, the line or byte offset, the field and the value.

CSV contract (`gcs estimate`): header with at least t,gx,gy,gz,ax,ay,az,mx,my,mz (any order; t in s,
gyro rad/s, accel m/s² specific force, mag in any consistent unit or empty when absent), optional
vn,ve,vd GPS velocity in m/s NED (empty when absent). Any right-handed sensor frame. A GPS sample
is emitted on the rows where the velocity changes (a velocity held between fixes is one fix).
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Iterator

import numpy as np

from gcs.sensors import IMU_TYPES, AttitudeSample, GpsSample, ImuSample, MessageSampler

Sample = ImuSample | GpsSample | AttitudeSample

CSV_COLUMNS = ("t", "gx", "gy", "gz", "ax", "ay", "az", "mx", "my", "mz")
CSV_GPS_COLUMNS = ("vn", "ve", "vd")


class InputError(ValueError):
    """Unreadable input; the message says which file, where, which field and what value."""


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


def read_csv(path: str) -> Iterator[Sample]:
    """IMU (and GPS velocity) samples from a CSV following the contract in the module docstring."""
    with open(path, newline="") as fh:
        reader = csv.reader(fh)
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
        last_vel = None
        for line, row in enumerate(reader, start=2):
            if not row or all(not cell.strip() for cell in row):
                continue
            if len(row) < len(header):
                raise InputError(f"{path}: line {line}: {len(row)} fields, header has {len(header)}")
            v = {name: _number(path, line, name, row[i], name not in ("mx", "my", "mz", *CSV_GPS_COLUMNS))
                 for name, i in col.items()}
            t = v["t"]
            mags = (v["mx"], v["my"], v["mz"])
            if any(m is None for m in mags) and not all(m is None for m in mags):
                raise InputError(f"{path}: line {line}: field 'mx'/'my'/'mz': give all three or none")
            mag = None if mags[0] is None else np.array(mags)
            if has_gps:
                vel = (v["vn"], v["ve"], v["vd"])
                if all(x is not None for x in vel) and vel != last_vel:
                    last_vel = vel
                    vn, ve, _ = vel
                    yield GpsSample(t, math.nan, math.nan, math.nan, math.hypot(vn, ve), math.atan2(ve, vn),
                                    np.array(vel), 3, "csv")
            yield ImuSample(t, np.array((v["gx"], v["gy"], v["gz"])), np.array((v["ax"], v["ay"], v["az"])),
                            mag, "csv")


def _connect(path: str):
    from pymavlink import mavutil

    return mavutil.mavlink_connection(path, dialect="ardupilotmega", robust_parsing=True)


def _tlog_imu_type(path: str) -> tuple[str, int]:
    """The IMU message type to use (RAW_IMU first) and the system that sends it."""
    conn = _connect(path)
    seen: dict[str, int] = {}
    while True:
        msg = conn.recv_match(type=list(IMU_TYPES))
        if msg is None:
            break
        seen.setdefault(msg.get_type(), msg.get_srcSystem())
        if "RAW_IMU" in seen:
            break
    conn.close()
    for kind in IMU_TYPES:
        if kind in seen:
            return kind, seen[kind]
    raise InputError(f"{path}: offset 0: no IMU message ({', '.join(IMU_TYPES)}) found; is this a .tlog?")


def read_tlog(path: str) -> Iterator[Sample]:
    """Samples of one vehicle from a MAVLink telemetry log, in arrival order, made by the same
    `MessageSampler` as the live pipeline: IMU from RAW_IMU (or the first IMU type present),
    GPS from GPS_RAW_INT, references from ATTITUDE, AHRS2 and SIMSTATE."""
    imu_type, system = _tlog_imu_type(path)
    sampler = MessageSampler(imu_type, system)
    conn = _connect(path)
    try:
        while (msg := conn.recv_match()) is not None:
            sample = sampler.feed(msg)
            if sample is not None:
                yield sample
    finally:
        conn.close()


def _dataflash(path: str):
    from gcs.sessions.dataflash import DataflashLog

    return DataflashLog(path)


def _ulog(path: str):
    from gcs.sessions.ulog import UlogFile

    return UlogFile(path)


READERS = {".csv": read_csv, ".tlog": read_tlog, ".bin": _dataflash, ".ulg": _ulog}


def read_samples(path: str) -> Iterator[Sample]:
    """The sample stream of a log file, by suffix; InputError for a missing file or unknown format."""
    if not os.path.isfile(path):
        raise InputError(f"{path}: no such file")
    suffix = os.path.splitext(path)[1].lower()
    reader = READERS.get(suffix)
    if reader is None:
        raise InputError(f"{path}: unknown input format {suffix!r}; known: {', '.join(READERS)}")
    return reader(path)
