"""The .bin samples as pymavlink's DFReader gives them: the reader gcs used before its own
column reader (gcs.logs.dataflash), kept here as the reference tests compare it against, record
by record: DFReader decodes each wanted record (its type index skips the others), per-record
converters make the sample objects, MAG rides on the IMU samples after it, PARM's COMPASS_DEC
or the WMM at the first 3D fix give declination changes. Its damage line comes from DFReader's
own notices (what it skipped, where it stopped).
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import re
import sys
import tempfile
from collections.abc import Iterator
from typing import TypeAlias

import numpy as np
from pymavlink.DFReader import DFMessage, DFReader_binary

from gcs.core.declination import WMM_EPOCH, decimal_year
from gcs.core.estimation import GainChange
from gcs.core.rotation import wrap_pi
from gcs.core.samples import (
    AttitudeSample,
    GpsSample,
    ImuSample,
    MagSample,
    mgauss_to_gauss,
    ms_to_s,
    ms_to_usec,
    usec_to_s,
)
from gcs.logs.dataflash import (
    GPS_EPOCH_UNIX,
    GPS_LEAP_SECONDS,
    GPS_TYPES,
    IMU_TYPES,
    MAG_TYPES,
    PARAM_TYPE,
    REFERENCES,
    TYPES,
)
from gcs.logs.logfile import InputError, LogFile
from gcs.logs.magnetometer import with_latest_mag

#: One decoded record. pymavlink ships no type information and creates each record's fields at
#: run time, so this is Any to mypy: the dynamic boundary of this reader, named here once.
DataflashRecord: TypeAlias = DFMessage


def record_instance(record: DataflashRecord) -> int:
    """The sensor instance: the `I` field of new logs, else the type's position (IMU2 → 1)."""
    instance = getattr(record, "I", None)
    if instance is not None:
        return int(instance)
    kind = record.get_type()
    for types in (IMU_TYPES, MAG_TYPES, GPS_TYPES):
        if kind in types:
            return types.index(kind)
    return 0


def record_time_us(record: DataflashRecord) -> int | None:
    """The record's time since boot in µs: TimeUS (µs), or TimeMS (ms) in ArduCopter 3.1-3.2
    logs; None for a record type without either (ArduCopter 3.1's ATT).

    The 3.1-3.2 GPS record is the exception: its TimeMS is the receiver's GPS time of week (what
    `Week` counts weeks of), not boot time; 3.2 adds the boot time as `T` (ms), 3.1 has none
    (None: the reader stamps it at the record before it, the loop it was logged in)."""
    time_us = getattr(record, "TimeUS", None)
    if time_us is not None:
        return int(time_us)
    if record.get_type() in GPS_TYPES:
        boot_ms = getattr(record, "T", None)
        return None if boot_ms is None else ms_to_usec(int(boot_ms))
    time_ms = getattr(record, "TimeMS", None)
    return None if time_ms is None else ms_to_usec(int(time_ms))


def _time_s(record: DataflashRecord) -> float:
    time_us = record_time_us(record)
    if time_us is None:
        raise InputError(f"{record.get_type()} record has neither TimeUS nor TimeMS")
    return usec_to_s(time_us)


def imu_from_dataflash(record: DataflashRecord, mag: MagSample | None = None) -> ImuSample:
    """IMU / IMU2 / IMU3 record: TimeUS µs or TimeMS ms, GyrX/Y/Z rad/s, AccX/Y/Z m/s² (body
    FRD); `mag` is the latest MAG reading, attached as a live RAW_IMU carries it."""
    sample = ImuSample(
        _time_s(record),
        np.array([record.GyrX, record.GyrY, record.GyrZ], dtype=float),
        np.array([record.AccX, record.AccY, record.AccZ], dtype=float),
        None,
        f"IMU[{record_instance(record)}]",
    )
    return with_latest_mag(sample, mag)


def mag_from_dataflash(record: DataflashRecord) -> MagSample | None:
    """MAG / MAG2 / MAG3 record: TimeUS µs or TimeMS ms, MagX/Y/Z milligauss, body FRD, offsets
    applied (what RAW_IMU carries). None for an all-zero field: no compass, as on the live path."""
    field = np.array([mgauss_to_gauss(record.MagX), mgauss_to_gauss(record.MagY), mgauss_to_gauss(record.MagZ)])
    if not field.any():
        return None
    return MagSample(_time_s(record), field, f"MAG[{record_instance(record)}]")


def gps_from_dataflash(record: DataflashRecord, t: float | None = None) -> GpsSample:
    """GPS / GPS2 record: TimeUS µs, or T ms in 3.2 (see record_time_us; `t` s where the record
    has no boot time), Lat/Lng degrees, Alt m, Spd m/s, GCrs deg, VZ m/s (down; 0 where the
    format lacks it, as GPS_RAW_INT), Status (AP_GPS fix status, whose values are MAVLink's
    GPS_FIX_TYPE)."""
    speed = float(record.Spd)
    course = math.radians(record.GCrs)
    vel_ned = np.array([speed * math.cos(course), speed * math.sin(course), float(getattr(record, "VZ", 0.0))])
    return GpsSample(
        _time_s(record) if t is None else t,
        float(record.Lat),
        float(record.Lng),
        float(record.Alt),
        speed,
        course,
        vel_ned,
        int(record.Status),
        f"GPS[{record_instance(record)}]",
    )


def gps_year(record: DataflashRecord) -> float:
    """The decimal year a GPS record was taken (GWk/GMS, or Week/TimeMS in 3.1-3.2 logs, GPS
    week and ms of the week); the WMM's epoch when the receiver has no time yet (week 0)."""
    week = getattr(record, "GWk", getattr(record, "Week", 0))
    ms = getattr(record, "GMS", getattr(record, "TimeMS", 0))
    if not week:
        return WMM_EPOCH
    return decimal_year(GPS_EPOCH_UNIX + int(week) * 604_800 + ms_to_s(int(ms)) - GPS_LEAP_SECONDS)


def attitude_from_dataflash(record: DataflashRecord, source: str) -> AttitudeSample:
    """ATT / AHR2 / SIM record: TimeUS µs or TimeMS ms, Roll/Pitch/Yaw in degrees (yaw 0..360;
    centidegrees in 3.2 logs, scaled by DFReader) → rad, yaw wrapped."""
    return AttitudeSample(
        _time_s(record),
        math.radians(record.Roll),
        math.radians(record.Pitch),
        wrap_pi(math.radians(record.Yaw)),
        source,
    )


#: What DFReader prints when it skips damage, with the offset: the first one is where the damage is.
_SKIP_NOTICE = re.compile(
    r"(bad header \S+(?: \S+)?|unknown msg type \S+ \(\d+\)|Skipped \d+ bad bytes) (?:in log )?at (?:offset )?(\d+)"
)


class DFReaderNotices:
    """DFReader prints every damaged spot it skips (one line per bad byte in a garbled header);
    a command answers in one line, so they are collected here and the first becomes the damage."""

    def __init__(self) -> None:
        self.text = io.StringIO()

    @contextlib.contextmanager
    def collected(self) -> Iterator[None]:
        with contextlib.redirect_stdout(self.text), contextlib.redirect_stderr(self.text):
            yield

    @contextlib.contextmanager
    def collected_from_fd(self) -> Iterator[None]:
        """Also what C code writes to file descriptor 2 (DFReader's fast indexer); anything else
        written there meanwhile is passed on afterwards."""
        sys.stderr.flush()
        saved = os.dup(2)
        with tempfile.TemporaryFile() as tmp:
            os.dup2(tmp.fileno(), 2)
            try:
                with self.collected():
                    yield
            finally:
                os.dup2(saved, 2)
                os.close(saved)
                tmp.seek(0)
                for line in tmp.read().decode(errors="replace").splitlines(keepends=True):
                    (self.text if _SKIP_NOTICE.search(line) else sys.stderr).write(line)

    def first(self) -> tuple[int, str] | None:
        """(offset, what DFReader said) of the first skipped damage, or None."""
        found = _SKIP_NOTICE.search(self.text.getvalue())
        return None if found is None else (int(found.group(2)), found.group(1))


class DfreaderLog(LogFile):
    """Iterates the samples of a .bin log in file order (see LogFile for what it reports): IMU
    instance `imu`, MAG and GPS instance 0, every reference."""

    def __iter__(self) -> Iterator[ImuSample | GpsSample | AttitudeSample | GainChange]:
        notices = DFReaderNotices()
        try:
            with notices.collected_from_fd():
                log = DFReader_binary(self.path)  # never mavlink_connection: it treats some paths as devices
        except Exception as exc:  # DFReader raises bare Exceptions on a bad header
            raise InputError(f"{self.path}: offset 0: not a DataFlash log ({exc})") from None
        mag: MagSample | None = None
        imu_instances: set[int] = set()
        untimed: set[str] = set()
        last_us: int | None = None  # the latest record time: a 3.1 GPS record's stamp
        while True:
            try:
                with notices.collected():
                    record = log.recv_match(type=list(TYPES))
            except Exception as exc:  # a record cut or garbled in a way DFReader cannot skip
                self.damage = f"{self.path}: offset {log.offset}: unreadable record ({exc}); stopped there"
                break
            if record is None:
                break
            kind = record.get_type()
            if kind == PARAM_TYPE:  # untimed in old logs: applied where it stands in the file
                time_us = record_time_us(record)
                if time_us is None:
                    self.counts[kind] += 1
                else:
                    self._seen(kind, time_us)
                change = self.declination.parameter(str(record.Name), float(record.Value))
                if change is not None:
                    yield change
                continue
            instance = record_instance(record)
            time_us = record_time_us(record)
            if time_us is None and kind in GPS_TYPES and last_us is not None:
                time_us = last_us  # ArduCopter 3.1: logged in the loop of the record before it
            if time_us is None:
                untimed.add(kind)
                continue
            last_us = time_us
            if kind in IMU_TYPES:
                imu_instances.add(instance)
                if instance == self.imu:
                    self._seen(kind, time_us)
                    yield imu_from_dataflash(record, mag)
            elif instance != 0:
                continue  # second compass / GPS: the first is the one the autopilot uses
            elif kind in MAG_TYPES:
                self._seen(kind, time_us)
                mag = mag_from_dataflash(record)
            elif kind in GPS_TYPES:
                self._seen(kind, time_us)
                gps = gps_from_dataflash(record, usec_to_s(time_us))
                yield gps
                if not self.declination.gps_fix:
                    change = self.declination.fix(gps.fix_type, gps.lat, gps.lon, gps.alt, gps_year(record))
                    if change is not None:
                        yield change
            else:
                self._seen(kind, time_us)
                yield attitude_from_dataflash(record, REFERENCES[kind])
        skipped = notices.first()
        if self.damage is None and skipped is not None:
            self.damage = f"{self.path}: offset {skipped[0]}: damaged data skipped ({skipped[1]})"
        if self.damage is None and log.offset < log.data_len:
            self.damage = (
                f"{self.path}: offset {log.offset}: log ends inside a record "
                f"({log.data_len - log.offset} bytes of {log.data_len} unread)"
            )
        self._note_missing(untimed)
        if not any(self.counts[kind] for kind in IMU_TYPES):
            found = f"instances in the log: {', '.join(map(str, sorted(imu_instances)))}" if imu_instances else "none"
            raise InputError(
                f"{self.path}: offset {log.offset}: no IMU records of instance {self.imu} ({found}); "
                "is this a DataFlash log?"
            )

    def _note_missing(self, untimed: set[str]) -> None:
        if untimed:
            self.notes.append(f"{self.path}: {', '.join(sorted(untimed))} records carry no time field; not used")
        if not any(self.counts[kind] for kind in MAG_TYPES):
            self.notes.append(f"{self.path}: no MAG records: heading from the gyro (and GPS course) only")
        if not any(self.counts[kind] for kind in GPS_TYPES):
            self.notes.append(f"{self.path}: no GPS records: no GPS aiding")
