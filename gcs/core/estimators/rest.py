"""Gyro bias from rest, for the estimators whose bias is otherwise learned only through the
attitude corrections (dcm's integrator, kf's tilt-only bias): at rest the true rate is zero, so
the gyro reads its own bias, on every axis, heading included. BROAD's trials start and end with
30-45 s of rest and a 0.2-0.5°/s bias (the same at both ends); learned only from the corrections,
its heading part stays, and in fast rotation (where the heading gains are low) it turns into a
2° heading bias. Rest is ekf's test (VQF's thresholds); ekf has it as zero-rate updates of its
bias state. Derivation and figures: docs/estimators/common.md "Gyro bias at rest".
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from gcs.core.estimators.jit import kernel
from gcs.core.estimators.kernels import State
from gcs.core.gains import Gain
from gcs.core.rotation import Vec3

#: The rest test's settings, shared by ekf (its zero-rate updates) and RestBias (VQF's thresholds).
REST_TEST_GAINS: tuple[Gain, ...] = (
    Gain("rest_gyro", 0.035, 0.0, 1.0, "rad/s", "bias-corrected rate below which the sensor may be at rest"),
    Gain("rest_acc", 0.5, 0.0, 10.0, "m/s²", "change of the accel vector allowed while at rest"),
    Gain("rest_time", 1.5, 0.1, 60.0, "s", "time both rest conditions must hold before it is rest"),
)
#: RestBias's: the test and the longest averaging time (VQF's biasForgettingTime).
REST_GAINS: tuple[Gain, ...] = REST_TEST_GAINS + (
    Gain("rest_bias_tau", 100.0, 0.0, 1000.0, "s", "bias = mean gyro at rest so far, at most this long; 0 = off"),
)
#: REST_GAINS values that switch it off (the thesis presets).
REST_OFF = {"rest_bias_tau": 0.0}


class RestTest:
    """Still for `rest_time` s: the bias-corrected rate below `rest_gyro` and the accel vector
    within `rest_acc` of where it was when the stillness began (and whatever else the caller
    requires, `still`)."""

    def __init__(self) -> None:
        self.since = -math.inf
        self.acc: Vec3 | None = None

    def interrupt(self) -> None:
        """A shock is not rest: the next sample starts the timing again."""
        self.acc = None

    def update(self, t: float, w: Vec3, accel: Vec3, g: Mapping[str, float], still: bool = True) -> bool:
        """At rest after this sample? w: the bias-corrected rate."""
        still = still and w[0] * w[0] + w[1] * w[1] + w[2] * w[2] < g["rest_gyro"] ** 2
        if still and self.acc is not None:
            dx, dy, dz = accel[0] - self.acc[0], accel[1] - self.acc[1], accel[2] - self.acc[2]
            still = dx * dx + dy * dy + dz * dz < g["rest_acc"] ** 2
        if not still or self.acc is None:
            self.since, self.acc = t, accel
        return t - self.since >= g["rest_time"]


class RestBias:
    """At rest (RestTest, with the GPS acceleration below `rest_acc` too): the bias estimate b is
    the gyro's mean over all the rest seen so far, at most the last τ = `rest_bias_tau` s:
    b += (ω − b)·dt/min(T, τ), T the time at rest so far. A steady acceleration that GPS sees is
    no rest; a slow turn taken for rest moves b by dt/T of it, not by all of it within 1 s."""

    def __init__(self) -> None:
        self.test = RestTest()
        self.at_rest = False
        self.total = 0.0  # time at rest so far (s)

    def update(
        self, t: float, gyro: Vec3, bias: Vec3, accel: Vec3, gps_acc: Vec3, dt: float, g: Mapping[str, float]
    ) -> Vec3:
        """The bias after this sample (unchanged unless at rest); gps_acc: GpsAcceleration.at(t)."""
        w = (gyro[0] - bias[0], gyro[1] - bias[1], gyro[2] - bias[2])
        a0, a1, a2 = gps_acc
        rest = self.test.update(t, w, accel, g, a0 * a0 + a1 * a1 + a2 * a2 < g["rest_acc"] ** 2)
        tau = g["rest_bias_tau"]
        self.at_rest = rest and tau > 0.0
        if not self.at_rest:
            return bias
        self.total += dt
        a = dt / min(self.total, tau)
        return (bias[0] + a * w[0], bias[1] + a * w[1], bias[2] + a * w[2])


#: Slots of RestBias in a compiled state, from the offset the estimator gives: since, acc set, acc (3),
#: total.
REST_SIZE = 6


def reset_rest(s: State, r: int) -> None:
    """A new RestBias at slot r."""
    s[r] = -math.inf
    s[r + 1 : r + 6] = 0.0


@kernel
def rest_still(
    s: State, r: int, t: float, wx: float, wy: float, wz: float, a0: float, a1: float, a2: float, still: bool,
    rest_gyro: float, rest_acc: float, rest_time: float,
) -> bool:  # fmt: skip
    """RestTest.update on slots r.. of s (since, acc set, acc (3)): at rest after this sample?"""
    still = still and wx * wx + wy * wy + wz * wz < rest_gyro**2
    if still and s[r + 1] != 0.0:
        dx, dy, dz = a0 - s[r + 2], a1 - s[r + 3], a2 - s[r + 4]
        still = dx * dx + dy * dy + dz * dz < rest_acc * rest_acc
    if not still or s[r + 1] == 0.0:
        s[r], s[r + 1], s[r + 2], s[r + 3], s[r + 4] = t, 1.0, a0, a1, a2
    return bool(t - s[r] >= rest_time)


@kernel
def rest_bias(
    s: State, r: int, t: float, gyro: State, b0: float, b1: float, b2: float, accel: State, gps_acc: Vec3,
    dt: float, rest_gyro: float, rest_acc: float, rest_time: float, tau: float,
) -> tuple[float, float, float]:  # fmt: skip
    """RestBias.update on slots r.. of s: the bias after this sample."""
    wx, wy, wz = gyro[0] - b0, gyro[1] - b1, gyro[2] - b2
    g0, g1, g2 = gps_acc
    still = g0 * g0 + g1 * g1 + g2 * g2 < rest_acc**2
    rest = rest_still(s, r, t, wx, wy, wz, accel[0], accel[1], accel[2], still, rest_gyro, rest_acc, rest_time)
    if not (rest and tau > 0.0):
        return b0, b1, b2
    s[r + 5] += dt
    a = dt / min(s[r + 5], tau)
    return b0 + a * wx, b1 + a * wy, b2 + a * wz
