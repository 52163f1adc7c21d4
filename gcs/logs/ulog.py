"""PX4 ULog (.ulg) files → the sample stream, through pyulog.

`sensor_combined` (gyro rad/s, accelerometer m/s² specific force, body FRD) → `ImuSample`,
carrying the latest magnetometer reading (see gcs.logs.magnetometer) from `vehicle_magnetometer`
(calibrated, body FRD, gauss) or, in logs without it, `sensor_mag` (gauss); `sensor_gps` or, in
older logs, `vehicle_gps_position` → `GpsSample`; `vehicle_attitude` (the onboard EKF2,
quaternion body→NED, w first) → the "onboard" reference. The topics are merged in timestamp
order (at equal timestamps a magnetometer reading first, so the IMU sample carries it). The
parameters (initial, then changed ones at their time) give EKF2_MAG_DECL (degrees) as a
declination `GainChange`, else the WMM's at the first 3D fix (see `VehicleDeclination`). pyulog
reads a damaged file up to the damage and flags corruption, but stops silently at a cut end;
`CutWatch` finds where a cut message starts, and `damage` says either.
"""

from __future__ import annotations

import heapq
import struct
from collections.abc import Iterator
from typing import BinaryIO, TypeAlias

import numpy as np
import numpy.typing as npt
from pyulog import ULog

from gcs.core.declination import WMM_EPOCH, decimal_year
from gcs.core.estimation import GainChange
from gcs.core.rotation import quat_to_euler
from gcs.core.samples import AttitudeSample, GpsSample, ImuSample, MagSample, degE7_to_deg, mm_to_m, usec_to_s
from gcs.logs.logfile import InputError, LogFile
from gcs.logs.magnetometer import with_latest_mag

IMU_TOPIC = "sensor_combined"
ATTITUDE_TOPIC = "vehicle_attitude"
#: Topics carrying each sensor, the preferred one first.
MAG_TOPICS = ("vehicle_magnetometer", "sensor_mag")
GPS_TOPICS = ("sensor_gps", "vehicle_gps_position")
#: One topic's columns, as pyulog decodes them (field name → one array per field).
Columns: TypeAlias = dict[str, npt.NDArray[np.generic]]
#: A parameter change: name, value (PX4's own unit).
Parameter: TypeAlias = tuple[str, float]
#: A merged row: timestamp µs, rank at equal timestamps, topic, what it carries.
Row: TypeAlias = tuple[int, int, str, ImuSample | MagSample | GpsSample | AttitudeSample | Parameter]
#: Row topic of a changed parameter.
PARAMETER_ROW = "parameter"


def imu_from_ulog_sensor_combined(
    timestamp_us: int, gyro_rad: npt.ArrayLike, accelerometer_m_s2: npt.ArrayLike
) -> ImuSample:
    """ULog `sensor_combined` row: timestamp µs, gyro_rad[3] rad/s, accelerometer_m_s2[3] (body FRD)."""
    return ImuSample(
        usec_to_s(timestamp_us),
        np.asarray(gyro_rad, dtype=float),
        np.asarray(accelerometer_m_s2, dtype=float),
        None,
        "sensor_combined",
    )


def mag_from_ulog(timestamp_us: int, field_gauss: npt.ArrayLike, topic: str) -> MagSample:
    """`vehicle_magnetometer` magnetometer_ga[3] or `sensor_mag` x, y, z: gauss; timestamp µs."""
    return MagSample(usec_to_s(timestamp_us), np.asarray(field_gauss, dtype=float), topic)


def gps_from_ulog(data: Columns, k: int, topic: str) -> GpsSample:
    """Row k of `sensor_gps` / `vehicle_gps_position`: timestamp µs; latitude_deg, longitude_deg
    (deg) and altitude_msl_m (m) since PX4 1.14, lat/lon (degE7) and alt (mm) before; vel_n/e/d_m_s
    and vel_m_s m/s, cog_rad rad, fix_type (MAVLink's GPS_FIX_TYPE values); the NED velocity only
    where vel_ned_valid."""
    if "latitude_deg" in data:
        lat, lon = float(data["latitude_deg"][k]), float(data["longitude_deg"][k])
        alt = float(data["altitude_msl_m"][k])
    else:
        lat, lon = degE7_to_deg(int(data["lat"][k])), degE7_to_deg(int(data["lon"][k]))
        alt = mm_to_m(int(data["alt"][k]))
    vel_ned = None
    if bool(data["vel_ned_valid"][k]):
        vel_ned = np.array([data["vel_n_m_s"][k], data["vel_e_m_s"][k], data["vel_d_m_s"][k]], dtype=float)
    return GpsSample(
        usec_to_s(int(data["timestamp"][k])),
        lat,
        lon,
        alt,
        float(data["vel_m_s"][k]),
        float(data["cog_rad"][k]),
        vel_ned,
        int(data["fix_type"][k]),
        topic,
    )


def attitude_from_ulog(timestamp_us: int, q: npt.ArrayLike) -> AttitudeSample:
    """`vehicle_attitude` row: timestamp µs, q[4] (w, x, y, z) body→NED → Z-Y-X Euler in rad."""
    return AttitudeSample(usec_to_s(timestamp_us), *quat_to_euler(np.asarray(q, dtype=float)), "onboard")


def _vectors(data: Columns, fields: tuple[str, ...]) -> npt.NDArray[np.float64]:
    return np.column_stack([np.asarray(data[f], dtype=float) for f in fields])


def _imu_rows(data: Columns) -> Iterator[Row]:
    gyro = _vectors(data, tuple(f"gyro_rad[{i}]" for i in range(3)))
    accel = _vectors(data, tuple(f"accelerometer_m_s2[{i}]" for i in range(3)))
    for k, timestamp in enumerate(data["timestamp"].tolist()):
        yield timestamp, 1, IMU_TOPIC, imu_from_ulog_sensor_combined(timestamp, gyro[k], accel[k])


def _mag_rows(data: Columns, topic: str) -> Iterator[Row]:
    names = ("magnetometer_ga[0]", "magnetometer_ga[1]", "magnetometer_ga[2]")
    field = _vectors(data, names if names[0] in data else ("x", "y", "z"))
    for k, timestamp in enumerate(data["timestamp"].tolist()):
        yield timestamp, 0, topic, mag_from_ulog(timestamp, field[k], topic)


def _gps_rows(data: Columns, topic: str) -> Iterator[Row]:
    for k, timestamp in enumerate(data["timestamp"].tolist()):
        yield timestamp, 2, topic, gps_from_ulog(data, k, topic)


def _parameter_rows(changed: list[tuple[int, str, float]]) -> Iterator[Row]:
    for timestamp, name, value in changed:
        yield timestamp, -1, PARAMETER_ROW, (name, float(value))


def _attitude_rows(data: Columns) -> Iterator[Row]:
    q = _vectors(data, tuple(f"q[{i}]" for i in range(4)))
    for k, timestamp in enumerate(data["timestamp"].tolist()):
        yield timestamp, 3, ATTITUDE_TOPIC, attitude_from_ulog(timestamp, q[k])


class CutWatch:
    """The file object pyulog reads through, noting a read the file's end cut short.

    pyulog reads every message as a 3-byte header (uint16 size, uint8 type), then `size` bytes,
    and ends quietly on a short read, whether at the clean end (no header byte left) or in the
    middle of a message. A short read that got some bytes, or a body read that got none after
    its header, is a cut: `cut` is (offset of the cut message, its length, bytes present). The
    offset is counted here rather than asked of the file (a tell() per read cost a third of the
    decoding).
    """

    def __init__(self, fh: BinaryIO) -> None:
        self.fh = fh
        self.cut: tuple[int, int, int] | None = None
        self._header: tuple[int, int] | None = None  # (offset, body size) of the last header read
        self._pos = fh.tell()

    def read(self, n: int = -1) -> bytes:
        at = self._pos
        data = self.fh.read(n)
        self._pos = at + len(data)
        header, self._header = self._header, None
        if 0 <= len(data) < n:
            if header is not None and header[1] == n:  # a body after its header
                self.cut = (header[0], 3 + n, 3 + len(data))
            elif data and n == 3:
                self.cut = (at, 3, len(data))
        elif n == 3 and len(data) == 3:
            self._header = (at, struct.unpack_from("<H", data)[0])
        return data

    def seek(self, offset: int, whence: int = 0) -> int:
        self._header = None
        self._pos = self.fh.seek(offset, whence)
        return self._pos

    def tell(self) -> int:
        return self._pos

    def close(self) -> None:
        pass  # the reader's `with` closes the file


class UlogFile(LogFile):
    """Iterates the samples of a .ulg in timestamp order (see LogFile for what it reports);
    `imu` selects the sensor_combined instance (multi_id)."""

    def __iter__(self) -> Iterator[ImuSample | GpsSample | AttitudeSample | GainChange]:
        try:
            with open(self.path, "rb") as fh:
                watch = CutWatch(fh)
                ulog = ULog(watch, [IMU_TOPIC, ATTITUDE_TOPIC, *MAG_TOPICS, *GPS_TOPICS])
        except OSError as exc:
            raise InputError(f"{self.path}: offset 0: cannot read ({exc.strerror})") from None
        except Exception as exc:  # pyulog raises plain Exceptions for a bad header or version
            raise InputError(f"{self.path}: offset 0: not a ULog file ({exc})") from None
        if ulog.file_corruption:
            self.damage = f"{self.path}: pyulog found corrupt data and skipped it; samples up to the damage are used"
        elif watch.cut is not None:
            at, length, present = watch.cut
            self.damage = (
                f"{self.path}: offset {at}: log ends inside a message ({present} of its {length} bytes); "
                "samples up to there are used"
            )
        imus = {d.multi_id: d.data for d in ulog.data_list if d.name == IMU_TOPIC and len(d.data["timestamp"])}
        if self.imu not in imus:
            found = f"instances in the log: {', '.join(map(str, sorted(imus)))}" if imus else "none"
            raise InputError(f"{self.path}: offset 0: no {IMU_TOPIC} instance {self.imu} ({found})")
        topics = {d.name: d.data for d in ulog.data_list if d.multi_id == 0}
        streams = [_imu_rows(imus[self.imu])]
        if ATTITUDE_TOPIC in topics:
            streams.append(_attitude_rows(topics[ATTITUDE_TOPIC]))
        mag_topic = next((t for t in MAG_TOPICS if t in topics), None)
        if mag_topic is None:
            self.notes.append(f"{self.path}: no {' or '.join(MAG_TOPICS)} topic: heading from the gyro only")
        else:
            streams.append(_mag_rows(topics[mag_topic], mag_topic))
        gps_topic = next((t for t in GPS_TOPICS if t in topics), None)
        if gps_topic is None:
            self.notes.append(f"{self.path}: no {' or '.join(GPS_TOPICS)} topic: no GPS aiding")
        else:
            streams.append(_gps_rows(topics[gps_topic], gps_topic))
        for name, value in ulog.initial_parameters.items():
            change = self.declination.parameter(name, float(value))
            if change is not None:
                yield change
        streams.append(_parameter_rows(ulog.changed_parameters))
        utc = topics[gps_topic].get("time_utc_usec") if gps_topic is not None else None
        mag: MagSample | None = None
        gps_row = 0
        for timestamp, _, topic, sample in heapq.merge(*streams, key=lambda row: row[:2]):
            if isinstance(sample, tuple):
                change = self.declination.parameter(*sample)
                if change is not None:
                    yield change
                continue
            self._seen(topic, timestamp)
            if isinstance(sample, MagSample):
                mag = sample
            elif isinstance(sample, ImuSample):
                yield with_latest_mag(sample, mag)
            elif isinstance(sample, GpsSample):
                yield sample
                if not self.declination.gps_fix:
                    year = decimal_year(usec_to_s(int(utc[gps_row]))) if utc is not None and utc[gps_row] else WMM_EPOCH
                    change = self.declination.fix(sample.fix_type, sample.lat, sample.lon, sample.alt, year)
                    if change is not None:
                        yield change
                gps_row += 1
            else:
                yield sample
