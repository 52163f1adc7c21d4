"""Sensor samples in SI units, body FRD, on the vehicle's clock.

Every source (a MAVLink stream, a DataFlash log, a ULog, a CSV file, the simulator) becomes
these samples; the estimators read nothing else. Each unit conversion lives in exactly one
function below, named after the source unit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

#: The vehicle clock going back by more than this (s) is a reboot: its clock starts again near 0.
#: Less (a log's time glitch) is not: the vehicle and what it set up (declination, EKF state) go on.
REBOOT_CLOCK_JUMP = 1.0


@dataclass(frozen=True, slots=True)
class ImuSample:
    """One inertial sample.

    t: vehicle time in seconds (from time_usec / time_boot_ms / log time; never arrival time).
    gyro: rad/s, body FRD.  accel: specific force in m/s², body FRD (about -9.81 on z when level).
    mag: magnetic field in body FRD in gauss, or None when the source has no magnetometer.
    source: where it came from, e.g. "RAW_IMU", "SCALED_IMU2", "HIGHRES_IMU", "IMU[0]".
    """

    t: float
    gyro: npt.NDArray[np.float64]
    accel: npt.NDArray[np.float64]
    mag: npt.NDArray[np.float64] | None = None
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
    vel_ned: npt.NDArray[np.float64] | None = None
    fix_type: int = 3
    source: str = ""


@dataclass(frozen=True, slots=True)
class MagSample:
    """A magnetometer reading logged on its own (DataFlash MAG, ULog vehicle_magnetometer).

    t: vehicle time in s. field: gauss, body FRD. The log readers attach the latest one to each
    following IMU sample (`ImuSample.mag`), as a live RAW_IMU message carries the latest compass
    reading, so the estimators see the same input offline and live.
    """

    t: float
    field: npt.NDArray[np.float64]
    source: str = ""


@dataclass(frozen=True, slots=True)
class BaroSample:
    """Static pressure in Pa and temperature in deg C."""

    t: float
    pressure: float
    temperature: float
    source: str = ""


# --- unit conversions: one function per source unit -------------------------------------------

#: Standard gravity (m/s²) used by MAVLink's milli-g fields.
G0 = 9.80665


def mg_to_mps2(value: float) -> float:
    """Milli-g (RAW_IMU / SCALED_IMU* accel) → m/s²."""
    return value * (G0 / 1000.0)


def mrad_to_rads(value: float) -> float:
    """Milli-radian per second (RAW_IMU / SCALED_IMU* gyro) → rad/s."""
    return value * 1e-3


def mgauss_to_gauss(value: float) -> float:
    """Milli-gauss (RAW_IMU / SCALED_IMU* mag, DataFlash MAG MagX/Y/Z) → gauss."""
    return value * 1e-3


def degE7_to_deg(value: int) -> float:
    """Degrees × 10^7 (GPS_RAW_INT lat/lon) → degrees."""
    return value * 1e-7


def cdeg_to_rad(value: float) -> float:
    """Centidegrees (GPS_RAW_INT cog) → radians."""
    return math.radians(value * 0.01)


def cm_to_m(value: float) -> float:
    """Centimetres, or cm/s (GPS_RAW_INT vel) → metres, or m/s."""
    return value * 0.01


def mm_to_m(value: float) -> float:
    """Millimetres (GPS_RAW_INT alt) → metres."""
    return value * 0.001


def hpa_to_pa(value: float) -> float:
    """Hectopascal (SCALED_PRESSURE press_abs) → pascal."""
    return value * 100.0


def cdegc_to_degc(value: float) -> float:
    """Centi-degrees Celsius (SCALED_PRESSURE temperature) → °C."""
    return value * 0.01


def usec_to_s(value: int) -> float:
    """Microseconds (time_usec, DataFlash TimeUS, ULog timestamp) → seconds."""
    return value * 1e-6


def ms_to_s(value: int) -> float:
    """Milliseconds (time_boot_ms) → seconds."""
    return value * 1e-3


def ms_to_usec(value: int) -> int:
    """Milliseconds (DataFlash TimeMS of ArduCopter 3.1-3.2) → integer microseconds, the logs'
    common clock unit, so a TimeMS log and a TimeUS log of the same instants give equal times."""
    return value * 1000


@dataclass(frozen=True, slots=True)
class AttitudeSample:
    """An attitude someone else estimated (or the simulator's truth), Z-Y-X Euler in rad.

    source: "onboard" (ATTITUDE), "ahrs2" (AHRS2), "truth" (SIMSTATE), or a log's equivalent.
    """

    t: float
    roll: float
    pitch: float
    yaw: float
    source: str = ""
