"""Whole-run attitude errors on arrays, for reports and what-if (the live, incremental
comparison is gcs.core.comparison)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from gcs.core.rotation import wrap_pi_array


def errors_against(series: npt.NDArray[np.float64], reference: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Estimator − reference in degrees at the reference times inside the estimator's time span,
    as an M×4 array (t s, roll, pitch, yaw error deg).

    Both inputs are N×4 arrays (t s, roll, pitch, yaw rad), t increasing. The estimator is interpolated
    linearly (yaw unwrapped first) and every error is wrapped to ±180°; a reference before the
    first or after the last estimate is not scored.
    """
    if len(series) < 2 or len(reference) == 0:
        return np.empty((0, 4))
    inside = (reference[:, 0] >= series[0, 0]) & (reference[:, 0] <= series[-1, 0])
    ref = reference[inside]
    out = np.empty((len(ref), 4))
    out[:, 0] = ref[:, 0]
    for k in range(3):
        est = np.unwrap(series[:, 1 + k]) if k == 2 else series[:, 1 + k]
        diff = np.interp(ref[:, 0], series[:, 0], est) - ref[:, 1 + k]
        out[:, 1 + k] = np.degrees(wrap_pi_array(diff))
    return out
