"""PX4 ULog (.ulg) files → the sample stream, through pyulog.

`sensor_combined` (gyro rad/s, accelerometer m/s² specific force, body FRD) → `ImuSample`;
`vehicle_attitude` (the onboard EKF2, quaternion body→NED, w first) → the "onboard" reference.
The two topics are merged in timestamp order (an IMU sample before an attitude with the same
timestamp). pyulog reads a damaged file up to the damage and flags it; `damage` says so.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterator

import numpy as np
import numpy.typing as npt
from pyulog import ULog

from gcs.core.rotation import quat_to_euler
from gcs.core.samples import AttitudeSample, ImuSample, usec_to_s
from gcs.logs.logfile import InputError, LogFile

IMU_TOPIC = "sensor_combined"
ATTITUDE_TOPIC = "vehicle_attitude"
#: Merge order at equal timestamps: the IMU sample first.
TOPICS = (IMU_TOPIC, ATTITUDE_TOPIC)


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


def attitude_from_ulog(timestamp_us: int, q: npt.ArrayLike) -> AttitudeSample:
    """`vehicle_attitude` row: timestamp µs, q[4] (w, x, y, z) body→NED → Z-Y-X Euler in rad."""
    return AttitudeSample(usec_to_s(timestamp_us), *quat_to_euler(np.asarray(q, dtype=float)), "onboard")


class UlogFile(LogFile):
    """Iterates the samples of a .ulg in timestamp order (see LogFile for what it reports)."""

    def __iter__(self) -> Iterator[ImuSample | AttitudeSample]:
        try:
            ulog = ULog(self.path, [IMU_TOPIC, ATTITUDE_TOPIC])
        except Exception as exc:  # pyulog raises plain Exceptions for a bad header or version
            raise InputError(f"{self.path}: offset 0: not a ULog file ({exc})") from None
        if ulog.file_corruption:
            self.damage = f"{self.path}: pyulog found corrupt data and skipped it; samples up to the damage are used"
        topics = {d.name: d.data for d in ulog.data_list if d.multi_id == 0}
        imu = topics.get(IMU_TOPIC)
        if imu is None or len(imu["timestamp"]) == 0:
            raise InputError(f"{self.path}: offset 0: no {IMU_TOPIC} topic; cannot estimate attitude")
        streams: list[Iterator[tuple[int, int, ImuSample | AttitudeSample]]] = [self._imu_rows(imu)]
        if ATTITUDE_TOPIC in topics:
            streams.append(self._attitude_rows(topics[ATTITUDE_TOPIC]))
        for timestamp, topic, sample in heapq.merge(*streams, key=lambda row: row[:2]):
            self._seen(TOPICS[topic], timestamp)
            yield sample

    def _imu_rows(self, data: dict[str, npt.NDArray[np.generic]]) -> Iterator[tuple[int, int, ImuSample]]:
        gyro = np.column_stack([data[f"gyro_rad[{i}]"] for i in range(3)])
        accel = np.column_stack([data[f"accelerometer_m_s2[{i}]"] for i in range(3)])
        for k, timestamp in enumerate(data["timestamp"].tolist()):
            yield timestamp, 0, imu_from_ulog_sensor_combined(timestamp, gyro[k], accel[k])

    def _attitude_rows(self, data: dict[str, npt.NDArray[np.generic]]) -> Iterator[tuple[int, int, AttitudeSample]]:
        q = np.column_stack([data[f"q[{i}]"] for i in range(4)])
        for k, timestamp in enumerate(data["timestamp"].tolist()):
            yield timestamp, 1, attitude_from_ulog(timestamp, q[k])
