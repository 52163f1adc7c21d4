"""PX4 ULog (.ulg) files → estimation inputs, in columns (gcs.logs.ulog_format reads the file).

`sensor_combined` (gyro rad/s, accelerometer m/s² specific force, body FRD) → IMU rows, carrying
the latest magnetometer reading (see gcs.logs.magnetometer) from `vehicle_magnetometer`
(calibrated, body FRD, gauss) or, in logs without it, `sensor_mag` (gauss), or, in PX4 1.7 and
older, `sensor_combined`'s own `magnetometer_ga` (calibrated, gauss; the latest reading, on each
row once one came: `magnetometer_timestamp_relative` is not RELATIVE_INVALID); `sensor_gps` or, in
older logs, `vehicle_gps_position` → GPS rows; `vehicle_attitude` (quaternion body→NED, w first)
→ the "onboard" reference: whichever estimator SYS_MC_EST_GROUP started (2: EKF2, PX4's default;
0 or 1: attitude_estimator_q, as in the shared px4-flight-sample.ulg, whose group is 1 and whose
ATT_*/LPE_* parameters and LPE's 10-state `estimator_status` say so). The topics are merged in
timestamp order (at equal timestamps a magnetometer reading first, so the IMU sample carries it),
as `heapq.merge` merges them. The parameters (initial, then changed ones at their time) give
EKF2_MAG_DECL (degrees) as a declination `GainChange`, else the WMM's at the first 3D fix (see
`VehicleDeclination`).
Everything is computed on whole columns; iterating a `UlogFile` gives the same inputs as objects.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable, Iterator, Mapping
from typing import Any, TypeAlias

import numpy as np
import numpy.typing as npt

from gcs.core.declination import WMM_EPOCH, decimal_year
from gcs.core.estimation import GainChange
from gcs.core.estimators.whole import InputKind as Kind
from gcs.core.estimators.whole import euler_of
from gcs.core.samples import AttitudeSample, GpsSample, ImuSample, degE7_to_deg, mm_to_m, usec_to_s
from gcs.logs.input_table import InputTable, gain_columns
from gcs.logs.logfile import InputError, LogFile
from gcs.logs.ulog_format import read_ulog
from gcs.mavlink.firmware_version import packed_version
from gcs.mavlink.identity import ulog_label

IMU_TOPIC = "sensor_combined"
ATTITUDE_TOPIC = "vehicle_attitude"
#: Topics carrying each sensor, the preferred one first.
MAG_TOPICS = ("vehicle_magnetometer", "sensor_mag")
#: The magnetometer inside sensor_combined (PX4 1.7 and older), as a stream of its own.
COMBINED_MAG = f"{IMU_TOPIC}.magnetometer_ga"
#: PX4's `*_timestamp_relative` for "no such reading".
RELATIVE_INVALID = 0x7FFFFFFF
GPS_TOPICS = ("sensor_gps", "vehicle_gps_position")
#: A topic's columns by field name (a structured array's fields, or a dict of arrays).
Columns: TypeAlias = Mapping[str, npt.NDArray[np.generic]]
Floats: TypeAlias = npt.NDArray[np.float64]
#: Streams merged, with their rank at equal timestamps (a changed parameter first).
PARAMETER, MAG, IMU, GPS, ATTITUDE = range(5)
RANK = {PARAMETER: -1, MAG: 0, IMU: 1, GPS: 2, ATTITUDE: 3}


def columns_of(rows: npt.NDArray[np.void]) -> Columns:
    """A structured array's fields as columns (views, no copy)."""
    return {name: rows[name] for name in rows.dtype.names or ()}


def _floats(data: Columns, fields: tuple[str, ...]) -> Floats:
    return np.column_stack([np.asarray(data[f], dtype=np.float64) for f in fields])


def converted(convert: Callable[[Any], Any], values: npt.ArrayLike) -> Floats:
    """A unit conversion of gcs.core.samples over a whole column, as float64."""
    return np.asarray(convert(np.asarray(values).astype(np.float64)), dtype=np.float64)


def seconds(data: Columns) -> Floats:
    """A topic's `timestamp` (µs) in seconds."""
    return converted(usec_to_s, data["timestamp"])


def imu_rows(data: Columns) -> Floats:
    """`sensor_combined` → N×7: t s, gyro_rad[3] rad/s, accelerometer_m_s2[3] (body FRD)."""
    fields = tuple(f"gyro_rad[{i}]" for i in range(3)) + tuple(f"accelerometer_m_s2[{i}]" for i in range(3))
    return np.column_stack([seconds(data), _floats(data, fields)])


def mag_field(data: Columns) -> Floats:
    """`vehicle_magnetometer` magnetometer_ga[3] or `sensor_mag` x, y, z → N×3 gauss."""
    names = ("magnetometer_ga[0]", "magnetometer_ga[1]", "magnetometer_ga[2]")
    return _floats(data, names if names[0] in data else ("x", "y", "z"))


def combined_mag(imu: Columns) -> Columns | None:
    """sensor_combined's own magnetometer (PX4 1.7 and older) as a magnetometer topic: on every
    row once a reading came, at the row's timestamp (so each IMU sample carries the reading its
    row holds); None where the topic has no magnetometer fields."""
    names = tuple(f"magnetometer_ga[{i}]" for i in range(3))
    if names[0] not in imu:
        return None
    valid = np.asarray(imu["magnetometer_timestamp_relative"]) != RELATIVE_INVALID
    return {name: np.asarray(imu[name])[valid] for name in ("timestamp", *names)}


def gps_rows(data: Columns) -> Floats:
    """`sensor_gps` / `vehicle_gps_position` → the input table's GPS rows: t s; latitude_deg,
    longitude_deg (deg) and altitude_msl_m (m) since PX4 1.14, lat/lon (degE7) and alt (mm) before;
    vel_m_s m/s, cog_rad rad, vel_n/e/d_m_s m/s (NaN where not vel_ned_valid), fix_type
    (MAVLink's GPS_FIX_TYPE values)."""
    if "latitude_deg" in data:
        position = _floats(data, ("latitude_deg", "longitude_deg", "altitude_msl_m"))
    else:
        lat, lon = converted(degE7_to_deg, data["lat"]), converted(degE7_to_deg, data["lon"])
        position = np.column_stack([lat, lon, converted(mm_to_m, data["alt"])])
    vel = _floats(data, ("vel_n_m_s", "vel_e_m_s", "vel_d_m_s"))
    vel[np.asarray(data["vel_ned_valid"]) == 0] = np.nan
    motion = _floats(data, ("vel_m_s", "cog_rad"))
    return np.column_stack([seconds(data), position, motion, vel, _floats(data, ("fix_type",))])


def attitude_rows(data: Columns) -> Floats:
    """`vehicle_attitude` q[4] (w, x, y, z) body→NED → N×4: t s, Z-Y-X Euler roll, pitch, yaw rad."""
    q = np.ascontiguousarray(_floats(data, tuple(f"q[{i}]" for i in range(4))))
    return np.column_stack([seconds(data), euler_of(q)])


def merge_order(keys: list[tuple[npt.NDArray[np.uint64], int]]) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """(stream, row) of every row of the streams (timestamps µs, rank) in `heapq.merge` order by
    (timestamp, rank): a stable sort when every stream is in time order, else heapq itself."""
    stream = np.concatenate([np.full(len(t), s, dtype=np.int64) for s, (t, _) in enumerate(keys)])
    row = np.concatenate([np.arange(len(t), dtype=np.int64) for t, _ in keys])
    if all(np.all(t[1:] >= t[:-1]) for t, _ in keys):
        t_all = np.concatenate([t for t, _ in keys])
        rank = np.concatenate([np.full(len(t), r, dtype=np.int64) for t, r in keys])
        order = np.lexsort((rank, t_all))
        return stream[order], row[order]

    def rows(s: int) -> Iterator[tuple[int, int, int, int]]:
        t, rank = keys[s]
        return ((ts, rank, s, k) for k, ts in enumerate(t.tolist()))

    merged = heapq.merge(*[rows(s) for s in range(len(keys))], key=lambda item: item[:2])
    pairs = np.array([(s, k) for _, _, s, k in merged], dtype=np.int64).reshape(-1, 2)
    return pairs[:, 0], pairs[:, 1]


def _firmware(info: dict[str, str]) -> str | None:
    """PX4's version from its info messages: "1.14.0 (fd483321)" from ver_sw_release (packed as
    AUTOPILOT_VERSION's) and the git hash ver_sw, "git fd483321" from the hash alone."""
    release = int(info.get("ver_sw_release", "0"))
    commit = info.get("ver_sw", "")[:8]
    if release:
        return packed_version(release) + (f" ({commit})" if commit else "")
    return f"git {commit}" if commit else None


class UlogFile(LogFile):
    """The inputs of a .ulg in timestamp order (see LogFile for what it reports); `imu` selects
    the sensor_combined instance (multi_id). `columns()` gives them as an input table, iterating
    the file as sample objects."""

    def __iter__(self) -> Iterator[ImuSample | GpsSample | AttitudeSample | GainChange]:
        yield from self.columns().inputs()

    def columns(self) -> InputTable:
        """The inputs as an input table, decoded on whole columns; reports as LogFile says."""
        contents = read_ulog(self.path, [IMU_TOPIC, ATTITUDE_TOPIC, *MAG_TOPICS, *GPS_TOPICS])
        if contents.damage:
            first, more = contents.damage[0], len(contents.damage) - 1
            self.damage = f"{self.path}: offset {first.offset}: {first.cause}"
            self.damage += f" ({more} more damaged places)" if more else ""
        self.vehicle = ulog_label(contents.info, contents.initial_parameters)
        self.firmware = _firmware(contents.info)
        if contents.dropouts:  # pyulog and Flight Review show them; the samples have gaps there
            offset, longest = max(contents.dropouts, key=lambda d: d[1])
            self.notes.append(
                f"{self.path}: {len(contents.dropouts)} logging dropouts, {sum(ms for _, ms in contents.dropouts)} ms "
                f"of data lost (the longest {longest} ms at offset {offset})"
            )
        topics = {name: columns_of(rows) for (name, multi_id), rows in contents.topics.items() if multi_id == 0}
        imus = sorted(m for name, m in contents.topics if name == IMU_TOPIC)
        if self.imu not in imus:
            found = f"instances in the log: {', '.join(map(str, imus))}" if imus else "none"
            # with no instance at all, where the file is cut or damaged comes first (a download cut
            # in the definitions has no topics), as a DataFlash log's error says it
            where = contents.damage[0] if contents.damage and not imus else None
            at = "offset 0:" if where is None else f"offset {where.offset}: {where.cause};"
            raise InputError(f"{self.path}: {at} no {IMU_TOPIC} instance {self.imu} ({found})")
        streams: dict[int, tuple[str, Columns]] = {IMU: (IMU_TOPIC, columns_of(contents.topics[IMU_TOPIC, self.imu]))}
        if ATTITUDE_TOPIC in topics:
            streams[ATTITUDE] = (ATTITUDE_TOPIC, topics[ATTITUDE_TOPIC])
        own_mag = combined_mag(streams[IMU][1])
        for kind, names, lacking in (
            (MAG, MAG_TOPICS, "heading from the gyro only"),
            (GPS, GPS_TOPICS, "no GPS aiding"),
        ):
            name = next((t for t in names if t in topics), None)
            if name is not None:
                streams[kind] = (name, topics[name])
            elif kind == MAG and own_mag is not None:
                streams[MAG] = (COMBINED_MAG, own_mag)
            else:
                self.notes.append(f"{self.path}: no {' or '.join(names)} topic: {lacking}")
        changed = contents.changed_parameters
        keys = {PARAMETER: np.array([t for t, _, _ in changed], dtype=np.uint64)}
        keys.update({kind: np.asarray(data["timestamp"]).astype(np.uint64) for kind, (_, data) in streams.items()})
        order = sorted(keys)
        which, row = merge_order([(keys[kind], RANK[kind]) for kind in order])
        which = np.asarray(order, dtype=np.int64)[which]
        self._report(which, row, keys, streams)
        return self._table(which, row, streams, contents.initial_parameters, changed)

    def _report(
        self, which: npt.NDArray[np.int64], row: npt.NDArray[np.int64], keys: dict[int, npt.NDArray[np.uint64]],
        streams: dict[int, tuple[str, Columns]],
    ) -> None:  # fmt: skip
        """counts per topic (sensor_combined's own magnetometer is no topic of its own) and the
        first and last timestamp of the merged topic rows."""
        for name, data in streams.values():
            if name != COMBINED_MAG:
                self.counts[name] += len(data["timestamp"])
        rows = np.flatnonzero(which != PARAMETER)
        if len(rows):
            first, last = rows[0], rows[-1]
            self.first_us = int(keys[int(which[first])][row[first]])
            self.last_us = int(keys[int(which[last])][row[last]])

    def _table(
        self, which: npt.NDArray[np.int64], row: npt.NDArray[np.int64], streams: dict[int, tuple[str, Columns]],
        initial: dict[str, float], changed: list[tuple[int, str, float]],
    ) -> InputTable:  # fmt: skip
        """The input table of the merged rows: magnetometer rows ride on the IMU rows after them,
        declination changes go where the per-sample rules make them."""
        imu = imu_rows(streams[IMU][1])
        mag_row = np.maximum.accumulate(np.where(which == MAG, row, -1))[which == IMU] if MAG in streams else None
        field = np.full((len(imu), 3), np.nan)
        if mag_row is not None:
            field[mag_row >= 0] = mag_field(streams[MAG][1])[mag_row[mag_row >= 0]]
        gps = gps_rows(streams[GPS][1]) if GPS in streams else np.empty((0, 10))
        gains = self._declination(which, row, streams, gps, initial, changed)
        inputs = np.flatnonzero((which != MAG) & (which != PARAMETER))
        slot = np.concatenate([2 * inputs + 1, np.array([s for s, _ in gains], dtype=np.int64)])
        order = np.argsort(slot, kind="stable")
        kind = np.concatenate([which[inputs], np.full(len(gains), -1, dtype=np.int64)])[order]
        codes = np.full(len(kind), Kind.GAIN, dtype=np.uint8)
        codes[kind == IMU] = np.where(mag_row >= 0, Kind.IMU_MAG, Kind.IMU) if mag_row is not None else Kind.IMU
        if GPS in streams:
            codes[kind == GPS] = np.where(np.asarray(streams[GPS][1]["vel_ned_valid"]) != 0, Kind.GPS_VEL, Kind.GPS)
        codes[kind == ATTITUDE] = Kind.ATTITUDE
        names = [IMU_TOPIC, "onboard", streams[GPS][0] if GPS in streams else GPS_TOPICS[0]]
        gain_estimator, gain_name, gain_value = gain_columns([change for _, change in gains], names)
        attitude = attitude_rows(streams[ATTITUDE][1]) if ATTITUDE in streams else np.empty((0, 4))
        return InputTable(
            kind=codes,
            imu=np.column_stack([imu, field]),
            imu_source=np.zeros(len(imu), dtype=np.uint16),
            gps=gps,
            gps_source=np.full(len(gps), 2, dtype=np.uint16),
            attitude=attitude,
            attitude_source=np.ones(len(attitude), dtype=np.uint16),
            gain_estimator=gain_estimator,
            gain_name=gain_name,
            gain_value=gain_value,
            names=tuple(names),
        )

    def _declination(
        self, which: npt.NDArray[np.int64], row: npt.NDArray[np.int64], streams: dict[int, tuple[str, Columns]],
        gps: Floats, initial: dict[str, float], changed: list[tuple[int, str, float]],
    ) -> list[tuple[int, GainChange]]:  # fmt: skip
        """The declination changes, each with its slot among the inputs (2 × merged position + 1
        for an input, so a parameter's change takes its own place and a fix's comes after it)."""
        gains: list[tuple[int, GainChange]] = []
        for name, value in initial.items():
            change = self.declination.parameter(name, value)
            if change is not None:
                gains.append((-1, change))
        utc = streams[GPS][1].get("time_utc_usec") if GPS in streams else None
        for position in np.flatnonzero((which == PARAMETER) | (which == GPS)).tolist():
            k = int(row[position])
            if which[position] == PARAMETER:
                _, name, value = changed[k]
                change, slot = self.declination.parameter(name, value), 2 * position
            elif self.declination.gps_fix:
                continue
            else:
                year = decimal_year(usec_to_s(int(utc[k]))) if utc is not None and utc[k] else WMM_EPOCH
                t, lat, lon, alt = gps[k, :4].tolist()
                change, slot = self.declination.fix(int(gps[k, 9]), lat, lon, alt, year), 2 * position + 2
            if change is not None:
                gains.append((slot, change))
        return gains
