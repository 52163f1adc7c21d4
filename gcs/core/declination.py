"""Magnetic declination: the vehicle's own parameter, else NOAA's World Magnetic Model (WMM2025).

The model is `pygeomag` (pure Python, no dependencies, ships NOAA's WMM coefficient files; MIT).
It agrees with NOAA's own `wmm-calculator` to 0.001° (checked at Bogotá and Canberra) without
that package's numpy + 8 MB geoid dependency. Works offline: the coefficients are in the wheel.
Why a fallback at all, and which source wins: docs/estimators/magnetic.md
"""

from __future__ import annotations

import datetime
import math
from collections.abc import Callable
from functools import cache
from typing import Any

from pygeomag import GeoMag

from gcs.core.estimation import GainChange

#: The WMM coefficient file used (valid 2025.0–2030.0; outside it the model is extrapolated).
WMM_MODEL = "wmm/WMM_2025.COF"
#: Year used when no date is known (the model's epoch).
WMM_EPOCH = 2025.0


@cache
def _model() -> Any:
    return GeoMag(coefficients_file=WMM_MODEL)


def decimal_year(unix_s: float) -> float:
    """UNIX time (s) → decimal year (2026.5 is early July 2026), UTC."""
    when = datetime.datetime.fromtimestamp(unix_s, datetime.UTC)
    start = datetime.datetime(when.year, 1, 1, tzinfo=datetime.UTC)
    end = datetime.datetime(when.year + 1, 1, 1, tzinfo=datetime.UTC)
    return when.year + (when - start) / (end - start)


def wmm_declination(lat_deg: float, lon_deg: float, alt_m: float = 0.0, year: float = WMM_EPOCH) -> float:
    """WMM declination at a geodetic position and decimal year: rad, east of true north positive
    (the `declination` gain's convention). Dates outside the model's life span are extrapolated."""
    result = _model().calculate(
        glat=float(lat_deg),
        glon=float(lon_deg),
        alt=float(alt_m) / 1000.0,
        time=float(year),
        allow_date_outside_lifespan=True,
    )
    return math.radians(float(result.d))


#: Vehicle parameters holding the magnetic declination, and their unit → rad conversion: the one
#: owner of these units, for PARAM_VALUE, DataFlash PARM records and ULog parameters alike.
DECLINATION_PARAMS: dict[str, Callable[[float], float]] = {
    "COMPASS_DEC": float,  # ArduPilot: radians
    "EKF2_MAG_DECL": math.radians,  # PX4: degrees (ekf2's mag_declination_deg)
}
#: GPS fix type (MAVLink GPS_FIX_TYPE, also AP_GPS and PX4's) from which the position is good
#: enough for the World Magnetic Model (3D).
WMM_MIN_FIX = 3


class VehicleDeclination:
    """Which declination the estimators use, and where it came from: the rule every input path
    (live PARAM_VALUE, a .tlog, DataFlash PARM records, ULog parameters) follows.

    The vehicle's own COMPASS_DEC / EKF2_MAG_DECL wins whenever it has given one; until then the
    World Magnetic Model's at the first 3D GPS fix. A vehicle value of exactly 0 is the firmware
    default (ArduPilot's COMPASS_DEC before its first GPS lock) and counts as unset: the WMM value
    wins over it. Each method returns the `GainChange` for every estimator when the value changes.
    `source` says which: "vehicle COMPASS_DEC", "WMM at lat,lon" or "none".
    """

    def __init__(self) -> None:
        self.value: float | None = None
        self.source = "none"
        self.vehicle: float | None = None  # the vehicle's own, non-zero value
        self.wmm: tuple[float, str] | None = None  # (declination, source) at the first 3D fix
        self.gps_fix = False

    def _set(self, value: float, source: str) -> GainChange | None:
        self.source = source
        if value == self.value:
            return None
        self.value = value
        return GainChange(None, "declination", value)

    def parameter(self, name: str, value: float) -> GainChange | None:
        """A parameter value in its own unit; None unless it is a declination that changes ours."""
        to_rad = DECLINATION_PARAMS.get(name)
        if to_rad is None or not math.isfinite(value):
            return None
        rad = to_rad(value)
        if not -math.pi <= rad <= math.pi:
            return None
        if rad == 0.0:  # the firmware default: not set yet (ArduPilot sets it after GPS lock)
            self.vehicle = None
            if self.wmm is not None:
                return self._set(*self.wmm)
            return self._set(0.0, f"vehicle {name} = 0 (unset)")
        self.vehicle = rad
        return self._set(rad, f"vehicle {name}")

    def fix(self, fix_type: int, lat_deg: float, lon_deg: float, alt_m: float, year: float) -> GainChange | None:
        """A GPS fix dated `year` (decimal); the first 3D one fixes the WMM value (used unless the
        vehicle has given its own)."""
        if self.gps_fix or fix_type < WMM_MIN_FIX or (lat_deg == 0 and lon_deg == 0):
            return None
        self.gps_fix = True
        self.wmm = (wmm_declination(lat_deg, lon_deg, alt_m, year), f"WMM at {lat_deg:.4f},{lon_deg:.4f}")
        if self.vehicle is not None:  # the vehicle's own value wins
            return None
        return self._set(*self.wmm)

    def reboot(self) -> None:
        """The vehicle rebooted: its next 3D fix is a new GPS lock."""
        self.gps_fix = False
