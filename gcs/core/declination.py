"""Magnetic declination from NOAA's World Magnetic Model (WMM2025), for when the vehicle gives none.

The model is `pygeomag` (pure Python, no dependencies, ships NOAA's WMM coefficient files; MIT).
It agrees with NOAA's own `wmm-calculator` to 0.001° (checked at Bogotá and Canberra) without
that package's numpy + 8 MB geoid dependency. Works offline: the coefficients are in the wheel.
Why a fallback at all, and which source wins: docs/estimators/magnetic.md
"""

from __future__ import annotations

import datetime
import math
from functools import cache
from typing import Any

from pygeomag import GeoMag

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
