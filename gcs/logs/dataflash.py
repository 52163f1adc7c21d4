"""ArduPilot DataFlash (.bin) logs → the sample stream, through pymavlink's DFReader.

DataFlash carries the IMU at the logging rate (the best data for estimator work): IMU instance
0 → `ImuSample`, GPS instance 0 → `GpsSample`, and three references: ATT ("onboard", the
primary EKF), AHR2 ("ahrs2", DCM) and SIM ("truth", SITL only), Roll/Pitch/Yaw in degrees.
Only those types are decoded (DFReader skips the others by its index, so this is much faster
than a full pass). A log cut mid-record (a crash, a partial download) is read up to the damage,
and `damage` says at which byte offset it is.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import TypeAlias

import numpy as np
from pymavlink.DFReader import DFMessage, DFReader_binary

from gcs.core.rotation import wrap_pi
from gcs.core.samples import AttitudeSample, GpsSample, ImuSample, usec_to_s
from gcs.logs.logfile import InputError, LogFile

#: DataFlash reference attitude record → reference name.
REFERENCES = {"ATT": "onboard", "AHR2": "ahrs2", "SIM": "truth"}
TYPES = ("IMU", "GPS", *REFERENCES)
#: One decoded record. pymavlink ships no type information and creates each record's fields at
#: run time, so this is Any to mypy: the dynamic boundary of this reader, named here once.
DataflashRecord: TypeAlias = DFMessage


def imu_from_dataflash(record: DataflashRecord) -> ImuSample:
    """DataFlash IMU record: TimeUS µs, GyrX/Y/Z rad/s, AccX/Y/Z m/s² (body FRD, no magnetometer)."""
    return ImuSample(
        usec_to_s(record.TimeUS),
        np.array([record.GyrX, record.GyrY, record.GyrZ], dtype=float),
        np.array([record.AccX, record.AccY, record.AccZ], dtype=float),
        None,
        f"IMU[{getattr(record, 'I', 0)}]",
    )


def gps_from_dataflash(record: DataflashRecord) -> GpsSample:
    """DataFlash GPS record: TimeUS µs, Lat/Lng degrees, Alt m, Spd m/s, GCrs deg, VZ m/s (down), Status."""
    speed = float(record.Spd)
    course = math.radians(record.GCrs)
    vel_ned = np.array([speed * math.cos(course), speed * math.sin(course), float(getattr(record, "VZ", 0.0))])
    return GpsSample(
        usec_to_s(record.TimeUS),
        float(record.Lat),
        float(record.Lng),
        float(record.Alt),
        speed,
        course,
        vel_ned,
        int(record.Status),
        "GPS",
    )


def attitude_from_dataflash(record: DataflashRecord, source: str) -> AttitudeSample:
    """ATT / AHR2 / SIM record: TimeUS µs, Roll/Pitch/Yaw in degrees (yaw 0..360) → rad, yaw wrapped."""
    return AttitudeSample(
        usec_to_s(record.TimeUS),
        math.radians(record.Roll),
        math.radians(record.Pitch),
        wrap_pi(math.radians(record.Yaw)),
        source,
    )


class DataflashLog(LogFile):
    """Iterates the samples of a .bin log in file order (see LogFile for what it reports);
    IMU and GPS records of instance 0 only."""

    def __iter__(self) -> Iterator[ImuSample | GpsSample | AttitudeSample]:
        try:
            log = DFReader_binary(self.path)  # never mavlink_connection: it treats some paths as devices
        except Exception as exc:  # DFReader raises bare Exceptions on a bad header
            raise InputError(f"{self.path}: offset 0: not a DataFlash log ({exc})") from None
        while True:
            try:
                record = log.recv_match(type=list(TYPES))
            except Exception as exc:  # a record cut or garbled in a way DFReader cannot skip
                self.damage = f"{self.path}: offset {log.offset}: unreadable record ({exc}); stopped there"
                break
            if record is None:
                break
            kind = record.get_type()
            if getattr(record, "I", 0) != 0:
                continue  # second IMU / GPS: the first instance is the one estimators use
            self._seen(kind, record.TimeUS)
            if kind == "IMU":
                yield imu_from_dataflash(record)
            elif kind == "GPS":
                yield gps_from_dataflash(record)
            else:
                yield attitude_from_dataflash(record, REFERENCES[kind])
        if self.damage is None and log.offset < log.data_len:
            self.damage = (
                f"{self.path}: offset {log.offset}: log ends inside a record "
                f"({log.data_len - log.offset} bytes of {log.data_len} unread)"
            )
        if self.counts["IMU"] == 0:
            raise InputError(f"{self.path}: offset {log.offset}: no IMU records; is this a DataFlash log?")
