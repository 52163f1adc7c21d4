"""Magnetic disturbance rejection shared by the estimators that take heading from the
magnetometer: a steel structure, a motor or a magnet near the sensor bends the field, and a
filter that keeps trusting it turns its heading (and, through the tilt compensation, more).
The test and its sources: docs/estimators/magnetic.md
"""

from __future__ import annotations

import math

#: VQF's defaults (Laidig & Seel 2023, `VQFParams`): low-pass of the current field norm and dip
#: (magCurrentTau), slow follow of the reference while undisturbed (magRefTau), turn rate needed
#: to time a new reference (magNewMinGyr).
MAG_CURRENT_TAU = 0.05
MAG_REF_TAU = 20.0
MAG_NEW_MIN_GYR = math.radians(20.0)


class MagDisturbance:
    """Is the magnetometer usable for heading? VQF's test (Laidig & Seel 2023).

    The field's norm and dip (earth frame), low-passed over MAG_CURRENT_TAU, must stay within
    norm_tol (relative) and dip_tol (rad) of the reference learned on the first sample; the
    reference follows them slowly (MAG_REF_TAU) while undisturbed. A disturbed field that stays
    steady for `relearn` seconds while the sensor turns faster than MAG_NEW_MIN_GYR becomes the new
    reference (turning proves it is fixed in the earth frame, not to the sensor).
    """

    def __init__(self) -> None:
        self.now: tuple[float, float] | None = None
        self.ref: tuple[float, float] | None = None
        self.cand: tuple[float, float] | None = None
        self.cand_time = 0.0
        self.disturbed = False

    def usable(
        self, norm: float, dip: float, dt: float, spin: float, norm_tol: float, dip_tol: float, relearn: float
    ) -> bool:
        if self.now is None or dt <= 0.0:
            self.now = (norm, dip)
        else:
            a = dt / (MAG_CURRENT_TAU + dt)
            n, d = self.now
            self.now = (n + a * (norm - n), d + a * (dip - d))
        norm, dip = self.now
        if self.ref is None:
            self.ref = (norm, dip)
        n0, d0 = self.ref
        if abs(norm - n0) <= norm_tol * n0 and abs(dip - d0) <= dip_tol:
            a = dt / (MAG_REF_TAU + dt)
            self.ref = (n0 + a * (norm - n0), d0 + a * (dip - d0))
            self.disturbed, self.cand, self.cand_time = False, None, 0.0
            return True
        self.disturbed = True
        c = self.cand
        if c is None or abs(norm - c[0]) > norm_tol * c[0] or abs(dip - c[1]) > dip_tol:
            self.cand, self.cand_time = (norm, dip), 0.0
        elif spin >= MAG_NEW_MIN_GYR:
            self.cand_time += dt
            if self.cand_time >= relearn:
                self.ref = (norm, dip)
                self.disturbed, self.cand, self.cand_time = False, None, 0.0
                return True
        return False
