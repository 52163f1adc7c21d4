"""Robust magnetometer heading, shared by every estimator that takes heading from the field
(dcm, kf, ekf): a steel structure, a motor or a magnet near the sensor bends the field, and a
filter that keeps trusting it turns its heading (and, through the tilt compensation, more).

Measurement model: m = Rᵀ m_E + b + d, with m_E the earth field (its norm and dip learned, its
horizontal part pointing to magnetic north), b a hard-iron offset fixed to the sensor (learned
online) and d whatever is left. The field is used only while m − b agrees with the reference in
norm, dip and heading; otherwise the estimator rides on the gyro (and GPS course where it has one)
and two candidates are timed: a steady sensor-frame offset (a magnet fixed to the body) and a
steady new earth field (one fixed to the place). Derivation and sources: docs/estimators/magnetic.md
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from gcs.core.gains import Gain
from gcs.core.rotation import Rows, Vec3, wrap_pi

#: VQF's defaults (Laidig & Seel 2023, `VQFParams`): low-pass of the current field norm and dip
#: (magCurrentTau), slow follow of the reference while undisturbed (magRefTau), turn rate needed
#: to time a new reference (magNewMinGyr).
MAG_CURRENT_TAU = 0.05
MAG_REF_TAU = 20.0
MAG_NEW_MIN_GYR = math.radians(20.0)
#: Turn (integrated |ω| dt) a sensor-frame offset must stay steady through before it is learned:
#: without turning, a heading error and a body-fixed offset look the same.
MAG_OFFSET_TURN = math.radians(90.0)
#: The offset must also have swung: were it fixed to the sensor, its earth-frame image R·o has moved
#: by MAG_OFFSET_SWING·|o| from where the window began (a turn of 30° across it) — which is how far
#: an offset fixed to the place (a steel floor, a magnet on the bench) would have moved in the
#: sensor frame, and the window restarts once that passes `mag_offset_tol`. Turning back and forth,
#: or about the offset's own axis, integrates to MAG_OFFSET_TURN without telling the two apart.
MAG_OFFSET_SWING = 2.0 * math.sin(math.radians(15.0))
#: Turn rate (rad/s) during which a steady disagreement between the field's heading and the
#: estimate's is timed (for `mag_relearn` s) before the estimate's heading is distrusted: the
#: field then agrees with itself from many attitudes and places, so it is the heading that is off
#: (a reference taken at rest over a place-fixed field). VQF's 20°/s let slow translation's jitter
#: time a body-fixed 100 µT magnet as well (BROAD trial 10: `dcm` 10×, `kf` 34× VQF).
MAG_HEADING_MIN_GYR = math.radians(60.0)

#: The test's settings, declared once; every estimator using MagneticHeading appends them.
MAG_GAINS: tuple[Gain, ...] = (
    Gain("mag_norm_tol", 0.1, 0.0, 10.0, "", "field-magnitude departure (of the reference) that rejects the mag"),
    Gain("mag_dip_tol", math.radians(10.0), 0.0, math.pi, "rad", "dip-angle departure that rejects the mag"),
    Gain(
        "mag_heading_tol", math.radians(20.0), 0.0, math.pi, "rad", "field heading vs gyro-held heading that rejects it"
    ),
    Gain("mag_relearn", 20.0, 0.0, 600.0, "s", "turning time in a steady new field before it is the reference"),
    Gain("mag_offset_time", 2.0, 0.0, 600.0, "s", "time a rejected field's sensor-frame offset is steady: hard iron"),
    Gain("mag_offset_tol", 0.1, 0.0, 1.0, "", "offset change (of the reference |m|) allowed while it is timed"),
)
#: Timing uncertainty of a field sample against the gyro's (s): the heading check widens by
#: |ω|·this while turning (BROAD's field lags its gyro by about 14 ms; RAW_IMU carries whatever
#: compass reading was latest).
MAG_TIME_SIGMA = 0.05
#: After (re)initialisation every field is used, and is the reference, until its norm and dip have
#: held within half the tolerances for this long (s): the tilt (hence the dip) of a filter
#: initialised away from the truth has to settle first.
MAG_WARMUP = 1.0
#: A learned hard-iron offset carries its timing window's error (the field's changes from place to
#: place, the heading error meanwhile: about 1 µT, degrees of heading under a strong magnet), while
#: the gyro, its bias learned at rest, drifts in heading mostly in fast turns (integrating picked
#: samples, an error that grows as |ω|²: BROAD at 47.6 Hz, 3° in 12 s at 450°/s). So after each
#: learned offset the heading corrections from the field get `weight` 0 until ∫|ω|² dt reaches
#: MAG_OFFSET_HOLD_SPIN2 (rad²/s: 17 s of BROAD's fast translation, 3 s of its fast rotation near a
#: magnet) or MAG_OFFSET_HOLD s have passed (VQF's magMaxRejectionTime: it coasts as long on a
#: rejected field), whichever is first, and come back to 1 over as much again or MAG_OFFSET_RAMP s.
MAG_OFFSET_HOLD_SPIN2 = 150.0
MAG_OFFSET_HOLD = 60.0
MAG_OFFSET_RAMP = 20.0
#: The least weight a Kalman heading update divides its noise by (weight 0 would divide by zero).
MAG_WEIGHT_MIN = 1e-6

#: MAG_GAINS values that switch the test off (the thesis presets).
MAG_OFF = {"mag_norm_tol": 10.0, "mag_dip_tol": math.pi, "mag_heading_tol": math.pi}


def _distance(norm: float, dip: float, ref: tuple[float, float], g: Mapping[str, float]) -> float:
    """How far (norm, dip) is from ref, in units of the tolerances (squared)."""
    dn = (norm - ref[0]) / max(g["mag_norm_tol"] * ref[0], 1e-9)
    dd = (dip - ref[1]) / max(g["mag_dip_tol"], 1e-9)
    return dn * dn + dd * dd


class MagneticHeading:
    """Which field, if any, to take heading from: m − b when it passes the test, else None.

    Test (VQF's, Laidig & Seel 2023, plus a heading check): the field m − b in the earth frame at
    the current estimate, its norm and dip low-passed over MAG_CURRENT_TAU, must be within
    `mag_norm_tol` (relative) and `mag_dip_tol` of the reference, and its heading within
    `mag_heading_tol` of the estimate's (while the estimate's heading is trusted: not after a
    relearn or a saturated gyro, until they agree again). The reference is the field itself until
    it has held still for MAG_WARMUP s, then follows it over MAG_REF_TAU while it passes. A
    rejected field is timed two ways:

    * hard iron: o = m − Rᵀ m_E (m_E from the reference at the gyro-held heading) steady within
      `mag_offset_tol`·|m_E| for `mag_offset_time` s, MAG_OFFSET_TURN of turning and a swing of
      MAG_OFFSET_SWING becomes b;
    * new earth field: norm and dip steady for `mag_relearn` s of turning faster than
      MAG_NEW_MIN_GYR become the reference (turning proves it is fixed to the place).

    And on every sample, a wrong heading: a steady heading disagreement for `mag_relearn` s of
    turning faster than MAG_HEADING_MIN_GYR distrusts the heading, makes the field the reference
    and keeps the old reference as rejected (a field nearer to it than to the reference fails).

    After a learned offset `weight` (what the estimators scale their heading correction by) is 0
    until ∫|ω|² dt reaches MAG_OFFSET_HOLD_SPIN2 or MAG_OFFSET_HOLD s pass, then back to 1: the gyro
    holds the heading.
    """

    def __init__(self) -> None:
        self.now: tuple[float, float] | None = None
        self.ref: tuple[float, float] | None = None
        self.cand: tuple[float, float] | None = None
        self.cand_time = 0.0
        self.offset: Vec3 = (0.0, 0.0, 0.0)
        self.offset_cand: Vec3 | None = None
        self.offset_n = 0
        self.offset_time = 0.0
        self.offset_turn = 0.0
        self.offset_rows: Rows = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))  # R at its start
        self.offset_swung = False  # has R·o moved by MAG_OFFSET_SWING·|o| since
        self.heading_trusted = False
        self.weight = 1.0  # weight of the heading from the field: 0 → 1 after a learned offset
        self.offset_age = math.inf  # time since the offset was learned (s)
        self.offset_age_spin2 = math.inf  # ∫|ω|² dt since the offset was learned (rad²/s)
        self.disturbed = False
        self.yaw_error = 0.0  # heading correction the last field asked for (rad)
        self.offsets_learned = 0
        self.relearned = 0
        self.age = 0.0  # time the reference has held still while settling (s)
        self.declination: float | None = None  # the one the heading check last compared against
        self.rejected: tuple[float, float] | None = None  # a reference the field proved disturbed
        self.head_cand: float | None = None  # mean heading disagreement being timed (rad)
        self.head_n = 0
        self.head_time = 0.0

    def distrust_heading(self) -> None:
        """The estimate's heading may be wrong (a saturated gyro): take the next field that fits."""
        self.heading_trusted = False

    def field(
        self, m: Vec3, rows: Rows, dt: float, spin: float, g: Mapping[str, float], settling: bool = False
    ) -> Vec3 | None:
        """m − b if it may be used for heading now, else None. rows: R (sensor → NED) by rows,
        spin: |ω| (rad/s), g: the estimator's gains (MAG_GAINS and `declination`); settling: the
        estimator knows its tilt is not yet right (the reference is then not kept)."""
        self.offset_age += dt
        self.offset_age_spin2 += spin * spin * dt
        after_time = (self.offset_age - MAG_OFFSET_HOLD) / MAG_OFFSET_RAMP
        after_spin = (self.offset_age_spin2 - MAG_OFFSET_HOLD_SPIN2) / MAG_OFFSET_HOLD_SPIN2
        self.weight = min(max(after_time, after_spin, 0.0), 1.0)
        bx, by, bz = self.offset
        mc = (m[0] - bx, m[1] - by, m[2] - bz)
        X, Y, Z = rows
        hn = X[0] * mc[0] + X[1] * mc[1] + X[2] * mc[2]
        he = Y[0] * mc[0] + Y[1] * mc[1] + Y[2] * mc[2]
        hd = Z[0] * mc[0] + Z[1] * mc[1] + Z[2] * mc[2]
        h = math.hypot(hn, he)
        if h < 1e-9:
            return None
        norm, dip = self._low_pass(math.hypot(h, hd), math.atan2(hd, h), dt)
        if settling:
            self.age = 0.0
        if self.age < MAG_WARMUP:  # settling: the reference is this field until it holds still
            self.age += dt
            r = self.ref
            if (
                r is None
                or abs(norm - r[0]) > 0.25 * g["mag_norm_tol"] * r[0]
                or abs(dip - r[1]) > 0.25 * g["mag_dip_tol"]
            ):
                self.ref, self.age = (norm, dip), 0.0
            self.heading_trusted = False
        assert self.ref is not None
        n0, d0 = self.ref
        if g["declination"] != self.declination:
            # A new declination moves the heading reference, not the field: the gyro-held heading
            # is then no evidence against the field until the estimate has turned to the new one.
            self.declination = g["declination"]
            self.heading_trusted = False
        self.yaw_error = wrap_pi(g["declination"] - math.atan2(he, hn))
        fits = abs(norm - n0) <= g["mag_norm_tol"] * n0 and abs(dip - d0) <= g["mag_dip_tol"]
        if self.heading_trusted and self._new_heading(self.yaw_error, dt, spin, g):
            # The field has disagreed with the heading by a steady angle through `mag_relearn` s of
            # turning, seen from many attitudes and places: the reference was the disturbed one
            # (taken at rest over a place-fixed field). Follow the field; remember the old one.
            self.heading_trusted = False
            self.rejected, self.ref = self.ref, (norm, dip)
            n0, d0 = self.ref
            fits = True
        if fits and self.rejected is not None:
            fits = _distance(norm, dip, self.rejected, g) > _distance(norm, dip, (n0, d0), g)
        agrees = abs(self.yaw_error) <= g["mag_heading_tol"] + spin * MAG_TIME_SIGMA or not self.heading_trusted
        if fits and agrees:
            a = dt / (MAG_REF_TAU + dt)
            self.ref = (n0 + a * (norm - n0), d0 + a * (dip - d0))
            self._accept()
            if abs(self.yaw_error) <= 0.5 * g["mag_heading_tol"]:
                self.heading_trusted = True
            return mc
        self.disturbed = True
        if self._hard_iron(m, rows, dt, spin, g):
            self.now = None
            self.offset_age, self.offset_age_spin2, self.weight = 0.0, 0.0, 0.0
            self.offsets_learned += 1
            self._accept()
            bx, by, bz = self.offset
            return (m[0] - bx, m[1] - by, m[2] - bz)
        if self._new_field(norm, dip, dt, spin, g):
            self.ref = (norm, dip)
            self.relearned += 1
            self.heading_trusted = False  # the estimate may have drifted while it was rejected
            self._accept()
            return mc
        return None

    def _low_pass(self, norm: float, dip: float, dt: float) -> tuple[float, float]:
        if self.now is None or dt <= 0.0:
            self.now = (norm, dip)
        else:
            a = dt / (MAG_CURRENT_TAU + dt)
            n, d = self.now
            self.now = (n + a * (norm - n), d + a * (dip - d))
        return self.now

    def _accept(self) -> None:
        self.disturbed = False
        self.cand, self.cand_time = None, 0.0
        self.offset_cand, self.offset_n, self.offset_time, self.offset_turn = None, 0, 0.0, 0.0

    def _hard_iron(self, m: Vec3, rows: Rows, dt: float, spin: float, g: Mapping[str, float]) -> bool:
        """Time the sensor-frame offset o = m − Rᵀ m_E (running mean); True once it is learned."""
        assert self.ref is not None
        n0, d0 = self.ref
        dec = g["declination"]
        e = (n0 * math.cos(d0) * math.cos(dec), n0 * math.cos(d0) * math.sin(dec), n0 * math.sin(d0))
        X, Y, Z = rows
        o = (
            m[0] - (X[0] * e[0] + Y[0] * e[1] + Z[0] * e[2]),
            m[1] - (X[1] * e[0] + Y[1] * e[1] + Z[1] * e[2]),
            m[2] - (X[2] * e[0] + Y[2] * e[1] + Z[2] * e[2]),
        )
        c = self.offset_cand
        if c is None or math.dist(o, c) > g["mag_offset_tol"] * n0:
            self.offset_cand, self.offset_n, self.offset_time, self.offset_turn = o, 1, 0.0, 0.0
            self.offset_rows, self.offset_swung = rows, False
            return False
        X0, Y0, Z0 = self.offset_rows
        sx = (X[0] - X0[0]) * c[0] + (X[1] - X0[1]) * c[1] + (X[2] - X0[2]) * c[2]
        sy = (Y[0] - Y0[0]) * c[0] + (Y[1] - Y0[1]) * c[1] + (Y[2] - Y0[2]) * c[2]
        sz = (Z[0] - Z0[0]) * c[0] + (Z[1] - Z0[1]) * c[1] + (Z[2] - Z0[2]) * c[2]
        if sx * sx + sy * sy + sz * sz >= MAG_OFFSET_SWING**2 * (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]):
            self.offset_swung = True
        self.offset_n += 1
        k = 1.0 / self.offset_n
        self.offset_cand = (c[0] + k * (o[0] - c[0]), c[1] + k * (o[1] - c[1]), c[2] + k * (o[2] - c[2]))
        self.offset_time += dt
        self.offset_turn += spin * dt
        turned = self.offset_turn >= MAG_OFFSET_TURN and self.offset_swung
        if self.offset_time >= g["mag_offset_time"] and turned:
            self.offset = self.offset_cand
            return True
        return False

    def _new_heading(self, ye: float, dt: float, spin: float, g: Mapping[str, float]) -> bool:
        """Time a steady heading disagreement while turning; True once the estimate's heading is
        to be distrusted (the field seen from many attitudes and places agrees with itself)."""
        tol = g["mag_heading_tol"]
        c = self.head_cand
        if c is None or abs(wrap_pi(ye - c)) > tol + spin * MAG_TIME_SIGMA:
            self.head_cand, self.head_n, self.head_time = ye, 1, 0.0
            return False
        self.head_n += 1
        self.head_cand = c = c + wrap_pi(ye - c) / self.head_n
        if abs(c) <= 0.5 * tol:
            self.head_cand, self.head_n, self.head_time = None, 0, 0.0
            return False
        if spin >= MAG_HEADING_MIN_GYR:
            self.head_time += dt
            if self.head_time >= g["mag_relearn"]:
                self.head_cand, self.head_n, self.head_time = None, 0, 0.0
                return True
        return False

    def _new_field(self, norm: float, dip: float, dt: float, spin: float, g: Mapping[str, float]) -> bool:
        """Time a steady new (norm, dip) while turning; True once it is to be the reference."""
        c = self.cand
        if c is None or abs(norm - c[0]) > g["mag_norm_tol"] * c[0] or abs(dip - c[1]) > g["mag_dip_tol"]:
            self.cand, self.cand_time = (norm, dip), 0.0
        elif spin >= MAG_NEW_MIN_GYR:
            self.cand_time += dt
            return self.cand_time >= g["mag_relearn"]
        return False
