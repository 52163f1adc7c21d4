"""Which inputs an estimator may be given at all.

One `inf` gyro reading used to leave a filter NaN for the rest of the flight, and one NaN
roll made every JSON answer invalid. A sample with a non-finite value, or one no sensor can
produce (faster than any MEMS gyro's full scale, harder than any accelerometer's, a field no
magnetometer reads), is refused before it reaches an estimator, and counted by its reason.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
import numpy.typing as npt

from gcs.core.estimators.jit import kernel
from gcs.core.samples import AttitudeSample, GpsSample, ImuSample

#: Largest magnitudes accepted: 4000 °/s (twice the usual 2000 °/s full scale), 160 g. The
#: magnetic field only has to be finite and not absurd: the estimators use its direction, and a
#: CSV may give it in any consistent unit (gauss, µT, counts).
MAX_RATE = 70.0  # rad/s
MAX_ACCEL = 1600.0  # m/s²
MAX_FIELD = 1e9
MAX_SPEED = 1000.0  # m/s, GPS
MAX_ALT, MIN_ALT = 1e6, -1e5  # m, GPS: above the Kármán line, below the deepest mine
MAX_ANGLE = 2 * math.pi  # rad, a reference's roll, pitch and yaw

# Each rule below exists twice: per sample (`refusal`, the live path) and per row of a whole
# table (the compiled and numpy forms, what-if and `--fast`). Both read the bounds above, and
# tests/test_plausibility.py holds every pair to the same verdicts on each bound's edges.


def _bounded(values: Iterable[float], limit: float) -> bool:
    """Every value finite and within ±limit (NaN fails every comparison). A plain loop: per
    sample on the live path, where `all()` over a generator cost twice as much."""
    for v in values:
        if not -limit <= v <= limit:
            return False
    return True


def refusal(item: ImuSample | GpsSample | AttitudeSample) -> str | None:
    """Why item must not reach an estimator ("imu:gyro" ...), or None when it may."""
    if not math.isfinite(item.t) or item.t < 0:
        return f"{type(item).__name__}:time"
    if isinstance(item, ImuSample):
        if not _bounded(item.gyro.tolist(), MAX_RATE):
            return "imu:gyro"
        if not _bounded(item.accel.tolist(), MAX_ACCEL):
            return "imu:accel"
        if item.mag is not None and not _bounded(item.mag.tolist(), MAX_FIELD):
            return "imu:mag"
        return None
    if isinstance(item, GpsSample):
        if not (-90 <= item.lat <= 90 and -180 <= item.lon <= 180 and MIN_ALT <= item.alt <= MAX_ALT):
            return "gps:position"
        if not (0 <= item.ground_speed <= MAX_SPEED and math.isfinite(item.course)):
            return "gps:speed"
        if item.vel_ned is not None and not _bounded(item.vel_ned.tolist(), MAX_SPEED):
            return "gps:velocity"
        return None
    if not _bounded((item.roll, item.pitch, item.yaw), MAX_ANGLE):
        return "attitude:angles"
    return None


@kernel
def _within(row: npt.NDArray[np.float64], lo: int, limit: float) -> bool:
    return bool(-limit <= row[lo] <= limit and -limit <= row[lo + 1] <= limit and -limit <= row[lo + 2] <= limit)


@kernel
def imu_row_accepted(row: npt.NDArray[np.float64], has_mag: bool) -> bool:
    """`refusal(...) is None` for one IMU row (t, gyro xyz, accel xyz, mag xyz), compiled."""
    t = row[0]
    if not (math.isfinite(t) and t >= 0):
        return False
    if not (_within(row, 1, MAX_RATE) and _within(row, 4, MAX_ACCEL)):
        return False
    return not has_mag or _within(row, 7, MAX_FIELD)


@kernel
def imu_rows_accepted(rows: npt.NDArray[np.float64], has_mag: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """`imu_row_accepted` of every row: the whole-run tables (has_mag: whether the row has a field)."""
    out = np.empty(rows.shape[0], dtype=np.bool_)
    for i in range(rows.shape[0]):
        out[i] = imu_row_accepted(rows[i], has_mag[i])
    return out


def attitude_rows_accepted(rows: npt.NDArray[np.float64]) -> npt.NDArray[np.bool_]:
    """`refusal(...) is None` for reference rows (t, roll, pitch, yaw): what whole runs score
    against, as the pipeline's comparison is given them (a NaN roll from a damaged log's ATT
    made `gcs replay --fast` print nan for the whole run)."""
    t, angles = rows[:, 0], rows[:, 1:4]
    accepted: npt.NDArray[np.bool_] = np.isfinite(t) & (t >= 0) & np.all(np.abs(angles) <= MAX_ANGLE, axis=1)
    return accepted


def gps_rows_accepted(rows: npt.NDArray[np.float64], has_vel: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """`refusal(...) is None` for GPS rows (t, lat, lon, alt, ground_speed, course, vel_ned xyz;
    has_vel: whether the row has a velocity), on whole columns."""
    t, lat, lon, alt, speed, course = (rows[:, i] for i in range(6))
    ok = np.isfinite(t) & (t >= 0)
    ok &= (lat >= -90) & (lat <= 90) & (lon >= -180) & (lon <= 180) & (alt >= MIN_ALT) & (alt <= MAX_ALT)
    ok &= (speed >= 0) & (speed <= MAX_SPEED) & np.isfinite(course)
    ok &= ~has_vel | np.all(np.abs(rows[:, 6:9]) <= MAX_SPEED, axis=1)
    accepted: npt.NDArray[np.bool_] = ok
    return accepted
