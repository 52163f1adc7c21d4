"""The per-sample refusal and the whole-table forms of each plausibility rule give one verdict.

The live path refuses a sample with `refusal`; what-if and `gcs replay --fast` refuse rows of
whole tables with the compiled and numpy forms. If the two drifted, a what-if would score
samples the live comparison never saw. Each field is pushed to each side of its bound, and to
NaN and ±inf, one at a time from a plausible row.
"""

import math

import numpy as np
import pytest

from gcs.core import plausibility as p
from gcs.core.samples import AttitudeSample, GpsSample, ImuSample


def edges(bound: float) -> list[float]:
    """Values around ±bound, and the non-finite ones."""
    nudge = max(abs(bound) * 1e-9, 1e-9)
    return [bound, bound + nudge, bound - nudge, -bound, -bound - nudge, math.nan, math.inf, -math.inf]


def one_field_off(base: list[float], bounds: dict[int, list[float]]) -> np.ndarray:
    """Rows equal to `base` but for one field set to one of its edge values."""
    rows = [base]
    for column, values in bounds.items():
        for value in values:
            row = list(base)
            row[column] = value
            rows.append(row)
    return np.array(rows, dtype=float)


def test_imu_rows_agree_with_refusal():
    base = [1.0, 0.1, -0.2, 0.3, 0.0, 0.0, -9.81, 0.2, 0.0, 0.4]
    bounds = {0: [0.0, -1e-9, math.nan, math.inf]}
    bounds |= {c: edges(p.MAX_RATE) for c in (1, 2, 3)}
    bounds |= {c: edges(p.MAX_ACCEL) for c in (4, 5, 6)}
    bounds |= {c: edges(p.MAX_FIELD) for c in (7, 8, 9)}
    rows = one_field_off(base, bounds)
    for has_mag in (True, False):
        flags = np.full(len(rows), has_mag)
        table = p.imu_rows_accepted(rows, flags)
        samples = [ImuSample(r[0], r[1:4], r[4:7], r[7:10] if has_mag else None) for r in rows]
        assert table.tolist() == [p.refusal(s) is None for s in samples]
    # the bound itself is accepted, a hair beyond it is not (written out, not derived)
    accepted = p.imu_rows_accepted(rows, np.full(len(rows), True))
    assert accepted[0] and accepted[1 + 4 + 0] and not accepted[1 + 4 + 1]


@pytest.mark.parametrize("has_vel", [True, False])
def test_gps_rows_agree_with_refusal(has_vel):
    base = [5.0, 47.4, 8.5, 430.0, 12.0, 1.0, 5.0, -3.0, 0.5, 3.0]  # t, lat, lon, alt, speed, course, vel, fix
    bounds = {0: [0.0, -1e-9, math.nan], 1: edges(90.0), 2: edges(180.0)}
    bounds |= {3: [p.MAX_ALT, p.MAX_ALT + 1, p.MIN_ALT, p.MIN_ALT - 1, math.nan, math.inf]}
    bounds |= {4: [0.0, -1e-9, p.MAX_SPEED, p.MAX_SPEED + 1e-6, math.nan], 5: [math.nan, math.inf, 7.0]}
    bounds |= {c: edges(p.MAX_SPEED) for c in (6, 7, 8)}
    rows = one_field_off(base, bounds)
    table = p.gps_rows_accepted(rows, np.full(len(rows), has_vel))
    samples = [GpsSample(*r[:6], r[6:9] if has_vel else None, int(r[9])) for r in rows]
    assert table.tolist() == [p.refusal(s) is None for s in samples]
    assert table[0] and not table[1 + 3 + 1]  # lat 90 + a hair is refused


def test_attitude_rows_agree_with_refusal():
    bounds = {0: [0.0, -1e-9, math.nan, math.inf]} | {c: edges(p.MAX_ANGLE) for c in (1, 2, 3)}
    rows = one_field_off([2.0, 0.1, -0.2, 3.0], bounds)
    table = p.attitude_rows_accepted(rows)
    assert table.tolist() == [p.refusal(AttitudeSample(*r)) is None for r in rows]
    assert table[0] and table[1 + 4] and not table[1 + 4 + 1]  # roll 2π accepted, 2π + a hair not
