"""ArduPilot DataFlash (.bin) logs → estimation inputs, in columns (gcs.logs.dataflash_format
reads the file).

Two generations of the format are read alike. Logs since ArduCopter 3.3 stamp records with
`TimeUS` (µs) and log every instance of a sensor under one record type with an instance field
`I`; ArduCopter 3.1-3.2 (the APM 2.5 era) stamp them with `TimeMS` (ms) and give each instance
its own type (IMU, IMU2, IMU3; MAG, MAG2; GPS, GPS2). The format's scaled fields (centidegrees,
1e-7 degrees, cm) arrive in the units DFReader gives, those the conversions below name.

The chosen IMU instance → IMU rows (gyro rad/s, accelerometer m/s², body FRD), carrying the
latest MAG of instance 0 (milligauss → gauss; an all-zero field is no compass; see
gcs.logs.magnetometer); GPS instance 0 → GPS rows; the references ATT ("onboard", the primary
EKF), AHR2 ("ahrs2", DCM) and SIM ("truth", SITL only); PARM records' COMPASS_DEC → a declination
`GainChange` (else the WMM's at the first 3D fix, see `VehicleDeclination`), as from a .tlog.
Everything is in file order and computed on whole columns; iterating a `DataflashLog` gives the
same inputs as objects. tests/dataflash_reference.py is the record-by-record reader on pymavlink's
DFReader that this one replaced, and the tests hold the two equal bit for bit.

Times: TimeUS, or TimeMS in ms; the 3.1-3.2 GPS record is the exception: its TimeMS is the
receiver's GPS time of week (what `Week` counts weeks of), not boot time; 3.2 adds the boot time
as `T` (ms), 3.1 has none, so such a record takes the time of the record before it (the loop it
was logged in). Record types with no time at all (ArduCopter 3.1's ATT) are left out and noted.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from gcs.core.declination import DECLINATION_PARAMS, WMM_EPOCH, decimal_year
from gcs.core.estimation import GainChange
from gcs.core.estimators.whole import InputKind as Kind
from gcs.core.samples import AttitudeSample, GpsSample, ImuSample, mgauss_to_gauss, ms_to_s, ms_to_usec, usec_to_s
from gcs.logs.dataflash_format import DataflashContents, RecordFormat, field_text, read_dataflash, scaled
from gcs.logs.dataflash_text import TextImage, text_image
from gcs.logs.input_table import InputTable, gain_columns
from gcs.logs.logfile import InputError, LogFile
from gcs.logs.ulog import converted
from gcs.mavlink.firmware_version import banner_version
from gcs.mavlink.identity import dataflash_label

#: Record types per sensor, the first instance first (new logs use the first name only).
IMU_TYPES = ("IMU", "IMU2", "IMU3")
MAG_TYPES = ("MAG", "MAG2", "MAG3")
GPS_TYPES = ("GPS", "GPS2")
#: DataFlash reference attitude record → reference name.
REFERENCES = {"ATT": "onboard", "AHR2": "ahrs2", "SIM": "truth"}
#: Parameter record (Name, Value; untimed in ArduCopter 3.1-3.2): where COMPASS_DEC comes from.
PARAM_TYPE = "PARM"
#: Text messages (the firmware's banner, "ArduCopter V4.7.0-dev (90700977)"): only name the vehicle.
MESSAGE_TYPE = "MSG"
TYPES = (*IMU_TYPES, *MAG_TYPES, *GPS_TYPES, *REFERENCES, PARAM_TYPE)
#: The columns each type must have to be read (else its FMT is refused as damage).
COLUMNS = {
    **dict.fromkeys(IMU_TYPES, ("GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ")),
    **dict.fromkeys(MAG_TYPES, ("MagX", "MagY", "MagZ")),
    **dict.fromkeys(GPS_TYPES, ("Status", "Lat", "Lng", "Alt", "Spd", "GCrs")),
    **dict.fromkeys(REFERENCES, ("Roll", "Pitch", "Yaw")),
    PARAM_TYPE: ("Name", "Value"),
    MESSAGE_TYPE: ("Message",),
}
#: GPS time (week 0 began 1980-01-06) → UNIX time, and GPS − UTC since 2017 (s).
GPS_EPOCH_UNIX = 315_964_800
GPS_LEAP_SECONDS = 18
#: No time field: the record is not used (a 3.1 GPS record takes the previous record's).
UNTIMED = -1
#: math.radians' factor, so whole columns convert exactly as the per-record readers did.
DEG_TO_RAD = math.pi / 180.0
Floats = npt.NDArray[np.float64]
Ints = npt.NDArray[np.int64]


@dataclass(frozen=True)
class Records:
    """The records of one type: rows (raw stored values), format, index among the file's
    records, sensor instance and time (µs, UNTIMED where the type has none)."""

    name: str
    rows: npt.NDArray[np.void]
    fmt: RecordFormat
    position: Ints
    instance: Ints
    time_us: Ints

    def seconds(self) -> Floats:
        """The records' times in s."""
        return converted(usec_to_s, self.time_us)

    def column(self, name: str, default: float | None = None) -> Floats:
        """A column in DFReader's units (float64); `default` where the format lacks it."""
        if name not in self.fmt.columns and default is not None:
            return np.full(len(self.rows), default)
        return scaled(self.rows, self.fmt, name)


def record_instance(name: str, rows: npt.NDArray[np.void], fmt: RecordFormat) -> Ints:
    """The sensor instance: the `I` field of new logs, else the type's position (IMU2 → 1)."""
    if "I" in fmt.columns:
        return np.asarray(rows["I"]).astype(np.int64)
    position = next((types.index(name) for types in (IMU_TYPES, MAG_TYPES, GPS_TYPES) if name in types), 0)
    return np.full(len(rows), position, dtype=np.int64)


def record_time_us(name: str, rows: npt.NDArray[np.void], fmt: RecordFormat) -> Ints:
    """The records' time since boot in µs: TimeUS, TimeMS (ms), a 3.2 GPS record's T (ms); else UNTIMED."""
    if "TimeUS" in fmt.columns:
        return np.asarray(rows["TimeUS"]).astype(np.int64)
    field = ("T" if "T" in fmt.columns else None) if name in GPS_TYPES else "TimeMS"
    if field is None or field not in fmt.columns:
        return np.full(len(rows), UNTIMED, dtype=np.int64)
    return np.asarray(rows[field]).astype(np.int64) * ms_to_usec(1)


def gps_year(gps: Records, k: int) -> float:
    """The decimal year GPS record k was taken (GWk/GMS, or Week/TimeMS in 3.1-3.2 logs, GPS week
    and ms of the week); the WMM's epoch when the receiver has no time yet (week 0)."""
    columns = gps.fmt.columns
    week = int(gps.rows[k]["GWk" if "GWk" in columns else "Week"]) if {"GWk", "Week"} & set(columns) else 0
    ms_field = "GMS" if "GMS" in columns else "TimeMS"
    ms = int(gps.rows[k][ms_field]) if ms_field in columns else 0
    if not week:
        return WMM_EPOCH
    return decimal_year(GPS_EPOCH_UNIX + week * 604_800 + ms_to_s(ms) - GPS_LEAP_SECONDS)


def gps_rows(gps: Records, t: Floats) -> Floats:
    """GPS / GPS2 → the input table's GPS rows: t s, Lat/Lng degrees, Alt m, Spd m/s, GCrs deg →
    rad, the NED velocity from speed and course with VZ m/s (down; 0 where the format lacks it,
    as GPS_RAW_INT), Status (AP_GPS fix status, whose values are MAVLink's GPS_FIX_TYPE). A few
    rows a second: the trigonometry is math's, per row, as the live path computes it. A course
    that is no number (a damaged record's infinity) gives no velocity (NaN: the row has none)."""
    speed, course_deg, vz = gps.column("Spd"), gps.column("GCrs"), gps.column("VZ", 0.0)
    course = [math.radians(c) for c in course_deg.tolist()]
    north = [s * math.cos(c) if math.isfinite(c) else math.nan for s, c in zip(speed.tolist(), course, strict=True)]
    east = [s * math.sin(c) if math.isfinite(c) else math.nan for s, c in zip(speed.tolist(), course, strict=True)]
    columns = (gps.column("Lat"), gps.column("Lng"), gps.column("Alt"), speed, course, north, east, vz)
    return np.column_stack([t, *columns, gps.column("Status")])


def attitude_rows(att: Records, t: Floats) -> Floats:
    """ATT / AHR2 / SIM: Roll/Pitch/Yaw in degrees (yaw 0..360; stored in centidegrees in 3.2
    logs) → rad, yaw wrapped into (-pi, pi] as `wrap_pi` does."""
    yaw = np.fmod(att.column("Yaw") * DEG_TO_RAD + math.pi, 2 * math.pi)
    yaw = np.where(yaw <= 0, yaw + 2 * math.pi, yaw) - math.pi
    return np.column_stack([t, att.column("Roll") * DEG_TO_RAD, att.column("Pitch") * DEG_TO_RAD, yaw])


def _vehicle(contents: DataflashContents) -> tuple[str | None, str | None]:
    """The log's vehicle label (from its MSG banners and the first value of each parameter) and
    firmware (its first banner's version)."""
    messages = contents.records.get(MESSAGE_TYPE)
    texts = [] if messages is None else [field_text(bytes(m)) for m in messages["Message"]]
    params: dict[str, float] = {}
    rows = contents.records.get(PARAM_TYPE)
    if rows is not None:
        values = scaled(rows, contents.formats[PARAM_TYPE], "Value").tolist()
        for raw, value in zip(rows["Name"].tolist(), values, strict=True):
            params.setdefault(field_text(raw), value)
    firmware = next((v for v in map(banner_version, texts) if v is not None), None)
    return dataflash_label(texts, params), firmware


class DataflashLog(LogFile):
    """The inputs of a .bin log in file order (see LogFile for what it reports): IMU instance
    `imu`, MAG and GPS instance 0, every reference. `columns()` gives them as an input table,
    iterating the log as sample objects."""

    def __iter__(self) -> Iterator[ImuSample | GpsSample | AttitudeSample | GainChange]:
        yield from self.columns().inputs()

    def columns(self) -> InputTable:
        """The inputs as an input table, decoded on whole columns; reports as LogFile says."""
        contents = self._contents()
        places = self._places(contents)
        if places:
            self.damage = f"{self.path}: {places[0]}"
            self.damage += f" ({len(places) - 1} more damaged places)" if len(places) > 1 else ""
        self.vehicle, self.firmware = _vehicle(contents)
        streams = self._streams(contents)
        return _Merged(self, streams, contents.offsets).table()

    def _contents(self) -> DataflashContents:
        return read_dataflash(self.path, COLUMNS)

    def _where(self, offset: int) -> str:
        """Where byte `offset` of the records is, as the user finds it in the file."""
        return f"offset {offset}"

    def _places(self, contents: DataflashContents) -> list[str]:
        """Each damaged place, first first: where, and what was found and done."""
        return [f"{self._where(d.offset)}: {d.cause}" for d in contents.damage]

    def _streams(self, contents: DataflashContents) -> dict[str, Records]:
        """Every wanted type's records, the untimed GPS ones of 3.1 stamped with the time of the
        record of these types before them; types without time noted and left out."""
        streams = {}
        for name, rows in contents.records.items():
            if name == MESSAGE_TYPE:
                continue
            fmt = contents.formats[name]
            instance, time_us = record_instance(name, rows, fmt), record_time_us(name, rows, fmt)
            streams[name] = Records(name, rows, fmt, contents.positions[name], instance, time_us)
        timed = [s for s in streams.values() if s.name != PARAM_TYPE]
        if timed:
            position = np.concatenate([s.position for s in timed])
            order = np.argsort(position, kind="stable")
            time_us = np.concatenate([s.time_us for s in timed])[order]
            latest = np.maximum.accumulate(np.where(time_us != UNTIMED, np.arange(len(time_us)), -1))
            filled = np.where(latest >= 0, time_us[np.maximum(latest, 0)], UNTIMED)
            stamped = np.empty_like(filled)
            stamped[order] = filled
            start = 0
            for s in timed:
                if s.name in GPS_TYPES:
                    s.time_us[:] = stamped[start : start + len(s.position)]
                start += len(s.position)
        untimed = sorted(name for name, s in streams.items() if name != PARAM_TYPE and (s.time_us == UNTIMED).any())
        if untimed:
            self.notes.append(f"{self.path}: {', '.join(untimed)} records carry no time field; not used")
        instances = [streams[n].instance for n in IMU_TYPES if n in streams] or [np.empty(0, dtype=np.int64)]
        imu_instances: list[int] = np.unique(np.concatenate(instances)).tolist()
        used = {}
        for name, s in streams.items():
            if name == PARAM_TYPE:  # every PARM, timed or not, applied where it stands in the file
                keep = np.ones(len(s.rows), dtype=np.bool_)
            else:
                keep = (s.instance == (self.imu if name in IMU_TYPES else 0)) & (s.time_us != UNTIMED)
            if keep.any():
                used[name] = Records(name, s.rows[keep], s.fmt, s.position[keep], s.instance[keep], s.time_us[keep])
        if imu_instances and self.imu not in imu_instances:  # --imu asks for one the log lacks
            *others, last = map(str, imu_instances)
            has = f"{', '.join(others)} and {last}" if others else last
            many = "s" if others else ""
            raise InputError(
                f"{self.path}: {self._where(0)}: no IMU instance {self.imu}; the log has IMU instance{many} {has}"
            )
        if not any(name in used for name in IMU_TYPES):
            found = f"instances in the log: {', '.join(map(str, imu_instances))}" if imu_instances else "none"
            places = self._places(contents)
            at = f"{self._where(contents.end)}:" if not places else f"{places[0]};"
            raise InputError(
                f"{self.path}: {at} no IMU records of instance {self.imu} ({found}); is this a DataFlash log?"
            )
        if not any(name in used for name in MAG_TYPES):
            self.notes.append(f"{self.path}: no MAG records: heading from the gyro (and GPS course) only")
        if not any(name in used for name in GPS_TYPES):
            self.notes.append(f"{self.path}: no GPS records: no GPS aiding")
        return used


class _Merged:
    """The used records of every type in file order, and the input table they make."""

    def __init__(self, log: DataflashLog, streams: dict[str, Records], offsets: Ints) -> None:
        self.log, self.streams, self.offsets = log, streams, offsets
        names = list(streams)
        self.which = np.concatenate([np.full(len(streams[n].position), k, dtype=np.int64) for k, n in enumerate(names)])
        self.row = np.concatenate([np.arange(len(streams[n].position), dtype=np.int64) for n in names])
        order = np.argsort(np.concatenate([streams[n].position for n in names]), kind="stable")
        self.which, self.row, self.names = self.which[order], self.row[order], names
        self.time_us = np.concatenate([streams[n].time_us for n in names])[order]

    def _is(self, *names: str) -> npt.NDArray[np.bool_]:
        """Which merged records are of one of these types."""
        return np.isin(self.which, [k for k, n in enumerate(self.names) if n in names])

    def _report(self) -> None:
        log = self.log
        for name, s in self.streams.items():
            log.counts[name] += len(s.position)
        timed = np.flatnonzero(self.time_us != UNTIMED)
        if len(timed):
            log.first_us, log.last_us = int(self.time_us[timed[0]]), int(self.time_us[timed[-1]])

    def _one(self, types: tuple[str, ...]) -> Records | None:
        """The type of a sensor that holds the instance used (one of IMU, IMU2, IMU3 ...)."""
        present = [self.streams[n] for n in types if n in self.streams]
        if len(present) > 1:
            names = ", ".join(s.name for s in present)
            at = self.log._where(int(self.offsets[present[1].position[0]]))  # position: an index among the records
            raise InputError(f"{self.log.path}: {at}: {names} records hold the same instance")
        return present[0] if present else None

    def table(self) -> InputTable:
        self._report()
        imu, mag = self._one(IMU_TYPES), self._one(MAG_TYPES)
        gps = self._one(GPS_TYPES)
        assert imu is not None
        is_imu = self._is(imu.name)
        imu_t = imu.seconds()
        imu_cols = [imu.column(c) for c in ("GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ")]
        field = np.full((len(imu_t), 3), np.nan)
        has_mag = np.zeros(len(imu_t), dtype=np.bool_)
        if mag is not None:
            mag_row = np.maximum.accumulate(np.where(self._is(mag.name), self.row, -1))[is_imu]
            values = np.column_stack([converted(mgauss_to_gauss, mag.column(c)) for c in ("MagX", "MagY", "MagZ")])
            nonzero: npt.NDArray[np.bool_] = np.any(values, axis=1)
            has_mag = (mag_row >= 0) & nonzero[np.maximum(mag_row, 0)]
            field[has_mag] = values[mag_row[has_mag]]
        gps_table = np.empty((0, 10)) if gps is None else gps_rows(gps, gps.seconds())
        references = [n for n in REFERENCES if n in self.streams]
        is_ref = self._is(*references)
        attitude = np.empty((0, 4))
        attitude_source = np.empty(0, dtype=np.uint16)
        source_names = [f"IMU[{self.log.imu}]", "GPS[0]", *REFERENCES.values()]
        if references:
            parts = {n: attitude_rows(self.streams[n], self.streams[n].seconds()) for n in references}
            ref_which = np.asarray(self.names, dtype=object)[self.which[is_ref]]
            ref_row = self.row[is_ref]
            attitude = np.empty((int(is_ref.sum()), 4))
            attitude_source = np.empty(len(attitude), dtype=np.uint16)
            for n in references:
                mine = ref_which == n
                attitude[mine] = parts[n][ref_row[mine]]
                attitude_source[mine] = source_names.index(REFERENCES[n])
        gains = self._declination(gps, gps_table)
        is_gps = self._is(*GPS_TYPES)
        inputs = np.flatnonzero(is_imu | is_gps | is_ref)
        slot = np.concatenate([2 * inputs + 1, np.array([s for s, _ in gains], dtype=np.int64)])
        order = np.argsort(slot, kind="stable")
        kind = np.full(len(slot), Kind.GAIN, dtype=np.uint8)
        input_kind = np.full(len(inputs), Kind.ATTITUDE, dtype=np.uint8)
        input_kind[is_imu[inputs]] = np.where(has_mag, Kind.IMU_MAG, Kind.IMU)
        input_kind[is_gps[inputs]] = np.where(np.isfinite(gps_table[:, 6:8]).all(axis=1), Kind.GPS_VEL, Kind.GPS)
        kind[: len(inputs)] = input_kind
        kind = kind[order]
        gain_estimator, gain_name, gain_value = gain_columns([change for _, change in gains], source_names)
        return InputTable(
            kind=kind,
            imu=np.column_stack([imu_t, *imu_cols, field]),
            imu_source=np.zeros(len(imu_t), dtype=np.uint16),
            gps=gps_table,
            gps_source=np.ones(len(gps_table), dtype=np.uint16),
            attitude=attitude,
            attitude_source=attitude_source,
            gain_estimator=gain_estimator,
            gain_name=gain_name,
            gain_value=gain_value,
            names=tuple(source_names),
        )

    def _declination(self, gps: Records | None, gps_table: Floats) -> list[tuple[int, GainChange]]:
        """The declination changes, each with its slot among the inputs (2 × merged position + 1
        for an input, so a PARM's change takes its own place and a fix's comes after its GPS)."""
        declination = self.log.declination
        events = self._is(*GPS_TYPES)
        params = self.streams.get(PARAM_TYPE)
        if params is not None:  # only declination parameters change anything: the rest are not looked at
            names, name_of = np.unique(np.asarray(params.rows["Name"]), return_inverse=True)
            ours = {name.encode() for name in DECLINATION_PARAMS}  # ASCII: equal as bytes up to a NUL iff as text
            wanted = np.array([n.split(b"\0", 1)[0] in ours for n in names.tolist()], dtype=np.bool_)[name_of]
            events |= self._is(PARAM_TYPE) & wanted[np.where(self._is(PARAM_TYPE), self.row, 0)]
            values = params.column("Value")
        gains: list[tuple[int, GainChange]] = []
        for position in np.flatnonzero(events).tolist():
            k = int(self.row[position])
            if self.names[self.which[position]] == PARAM_TYPE:
                change = declination.parameter(field_text(names[name_of[k]]), float(values[k]))
                slot = 2 * position + 1
            elif declination.gps_fix or gps is None:
                continue
            else:
                lat, lon, alt = gps_table[k, 1:4].tolist()
                year = gps_year(gps, k)
                change, slot = declination.fix(int(gps_table[k, 9]), lat, lon, alt, year), 2 * position + 2
            if change is not None:
                gains.append((slot, change))
        return gains


class DataflashTextLog(DataflashLog):
    """A DataFlash text log (.log, gcs.logs.dataflash_text): its records read as a .bin's, every
    place named by its line."""

    _image: TextImage

    def _contents(self) -> DataflashContents:
        self._image = text_image(self.path, COLUMNS)
        return read_dataflash(self.path, COLUMNS, self._image.buf)

    def _where(self, offset: int) -> str:
        return f"line {self._image.line_at(offset)}"

    def _places(self, contents: DataflashContents) -> list[str]:
        found = [(self._image.line_at(d.offset), d.cause) for d in contents.damage]
        return [f"line {line}: {cause}" for line, cause in sorted(self._image.damage + found, key=lambda p: p[0])]
