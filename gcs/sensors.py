"""Sensor samples in SI units, body FRD, on the vehicle's clock.

Every source (a MAVLink stream, a DataFlash log, a ULog, a CSV file, the simulator) becomes
these samples; the estimators read nothing else. Each unit conversion lives in exactly one
function below, named after the source unit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True)
class ImuSample:
    """One inertial sample.

    t: vehicle time in seconds (from time_usec / time_boot_ms / log time; never arrival time).
    gyro: rad/s, body FRD.  accel: specific force in m/s², body FRD (about -9.81 on z when level).
    mag: magnetic field in body FRD in gauss, or None when the source has no magnetometer.
    source: where it came from, e.g. "RAW_IMU", "SCALED_IMU2", "HIGHRES_IMU", "IMU[0]".
    """

    t: float
    gyro: np.ndarray
    accel: np.ndarray
    mag: np.ndarray | None = None
    source: str = ""


@dataclass(frozen=True, slots=True)
class GpsSample:
    """One GPS fix from the receiver itself (never the autopilot's fused estimate).

    t: vehicle time in s. lat/lon in degrees, alt in m (MSL). ground_speed m/s, course rad
    (0 = true north, clockwise). vel_ned m/s when the source has it, else None.
    fix_type: MAVLink GPS_FIX_TYPE (>= 3 is a 3-D fix).
    """

    t: float
    lat: float
    lon: float
    alt: float
    ground_speed: float
    course: float
    vel_ned: np.ndarray | None = None
    fix_type: int = 3
    source: str = ""


@dataclass(frozen=True, slots=True)
class BaroSample:
    """Static pressure in Pa and temperature in deg C."""

    t: float
    pressure: float
    temperature: float
    source: str = ""
