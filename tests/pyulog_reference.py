"""The .ulg samples as pyulog gives them: the reader gcs used before its own column reader, kept
here as the reference tests compare gcs.logs.ulog against (pyulog decodes; per-topic rows become
sample objects, sensor_combined's own magnetometer too where no magnetometer topic is logged;
heapq merges them in timestamp order, a magnetometer reading first at equal timestamps;
EKF2_MAG_DECL or the WMM at the first 3D fix as declination changes)."""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field

import numpy as np
from pyulog import ULog

from gcs.core.declination import WMM_EPOCH, VehicleDeclination, decimal_year
from gcs.core.rotation import quat_to_euler
from gcs.core.samples import AttitudeSample, GpsSample, ImuSample, MagSample
from gcs.logs.magnetometer import with_latest_mag

MAG_TOPICS = ("vehicle_magnetometer", "sensor_mag")
GPS_TOPICS = ("sensor_gps", "vehicle_gps_position")


@dataclass
class Reference:
    samples: list = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)
    first_us: int | None = None
    last_us: int | None = None
    corrupt: bool = False


def _vectors(data, names):
    return np.column_stack([np.asarray(data[f], dtype=float) for f in names])


def _gps(data, k: int, topic: str) -> GpsSample:
    if "latitude_deg" in data:
        lat, lon = float(data["latitude_deg"][k]), float(data["longitude_deg"][k])
        alt = float(data["altitude_msl_m"][k])
    else:
        lat, lon, alt = int(data["lat"][k]) * 1e-7, int(data["lon"][k]) * 1e-7, int(data["alt"][k]) * 0.001
    vel = None
    if bool(data["vel_ned_valid"][k]):
        vel = np.array([data["vel_n_m_s"][k], data["vel_e_m_s"][k], data["vel_d_m_s"][k]], dtype=float)
    t = int(data["timestamp"][k]) * 1e-6
    speed, course = float(data["vel_m_s"][k]), float(data["cog_rad"][k])
    return GpsSample(t, lat, lon, alt, speed, course, vel, int(data["fix_type"][k]), topic)


def read(path: str, imu: int = 0) -> Reference:
    """Every sample of the .ulg at path, in the order gcs's reader must give them."""
    ulog = ULog(path, ["sensor_combined", "vehicle_attitude", *MAG_TOPICS, *GPS_TOPICS])
    out = Reference(corrupt=ulog.file_corruption)
    imus = {d.multi_id: d.data for d in ulog.data_list if d.name == "sensor_combined"}
    topics = {d.name: d.data for d in ulog.data_list if d.multi_id == 0}
    rows = []  # (timestamp, rank, topic, sample)
    data = imus[imu]
    gyro = _vectors(data, [f"gyro_rad[{i}]" for i in range(3)])
    accel = _vectors(data, [f"accelerometer_m_s2[{i}]" for i in range(3)])
    rows.append(
        [(ts, 1, "sensor_combined", ImuSample(ts * 1e-6, gyro[k], accel[k], None, "sensor_combined"))
         for k, ts in enumerate(data["timestamp"].tolist())]
    )  # fmt: skip
    if "vehicle_attitude" in topics:
        data = topics["vehicle_attitude"]
        q = _vectors(data, [f"q[{i}]" for i in range(4)])
        rows.append(
            [(ts, 3, "vehicle_attitude", AttitudeSample(ts * 1e-6, *quat_to_euler(q[k]), "onboard"))
             for k, ts in enumerate(data["timestamp"].tolist())]
        )  # fmt: skip
    mag_topic = next((t for t in MAG_TOPICS if t in topics), None)
    names = [f"magnetometer_ga[{i}]" for i in range(3)]
    if mag_topic is not None:
        data = topics[mag_topic]
        values = _vectors(data, names if names[0] in data else ["x", "y", "z"])
        rows.append(
            [(ts, 0, mag_topic, MagSample(ts * 1e-6, values[k], mag_topic))
             for k, ts in enumerate(data["timestamp"].tolist())]
        )  # fmt: skip
    elif names[0] in imus[imu]:  # PX4 1.7 and older: the latest reading on each sensor_combined row
        data, topic = imus[imu], "sensor_combined.magnetometer_ga"
        values = _vectors(data, names)
        rows.append(
            [(ts, 0, topic, MagSample(ts * 1e-6, values[k], topic))
             for k, ts in enumerate(data["timestamp"].tolist())
             if data["magnetometer_timestamp_relative"][k] != 0x7FFFFFFF]
        )  # fmt: skip
    gps_topic = next((t for t in GPS_TOPICS if t in topics), None)
    if gps_topic is not None:
        data = topics[gps_topic]
        rows.append([(ts, 2, gps_topic, _gps(data, k, gps_topic)) for k, ts in enumerate(data["timestamp"].tolist())])
    declination = VehicleDeclination()
    for name, value in ulog.initial_parameters.items():
        change = declination.parameter(name, float(value))
        if change is not None:
            out.samples.append(change)
    rows.append([(ts, -1, "parameter", (name, float(value))) for ts, name, value in ulog.changed_parameters])
    utc = topics[gps_topic].get("time_utc_usec") if gps_topic is not None else None
    mag, gps_row, counts = None, 0, {}
    for ts, _, topic, sample in heapq.merge(*rows, key=lambda row: row[:2]):
        if isinstance(sample, tuple):
            change = declination.parameter(*sample)
            if change is not None:
                out.samples.append(change)
            continue
        if topic != "sensor_combined.magnetometer_ga":  # rows of sensor_combined, counted there
            counts[topic] = counts.get(topic, 0) + 1
        out.first_us = ts if out.first_us is None else out.first_us
        out.last_us = ts
        if isinstance(sample, MagSample):
            mag = sample
        elif isinstance(sample, ImuSample):
            out.samples.append(with_latest_mag(sample, mag))
        elif isinstance(sample, GpsSample):
            out.samples.append(sample)
            if not declination.gps_fix:
                year = decimal_year(int(utc[gps_row]) * 1e-6) if utc is not None and utc[gps_row] else WMM_EPOCH
                change = declination.fix(sample.fix_type, sample.lat, sample.lon, sample.alt, year)
                if change is not None:
                    out.samples.append(change)
            gps_row += 1
        else:
            out.samples.append(sample)
    out.counts = counts
    return out


def assert_same_samples(ours: list, reference: list) -> None:
    """Every sample equal, field by field and bit for bit (arrays too), in the same order."""
    assert len(ours) == len(reference)
    for k, (a, b) in enumerate(zip(ours, reference, strict=True)):
        assert type(a) is type(b), (k, a, b)
        for name in a.__dataclass_fields__:
            x, y = getattr(a, name), getattr(b, name)
            if isinstance(y, np.ndarray) or isinstance(x, np.ndarray):
                assert x is not None and y is not None and x.dtype == y.dtype, (k, name, x, y)
                assert np.array_equal(x, y), (k, name, x, y)
            else:
                assert type(x) is type(y) and x == y, (k, name, x, y)
