"""The Python side of a compiled estimator: the reference class's state and methods over the kernel
state array (gcs.core.estimators.kernels), so that a compiled class is its reference class with
`Compiled` (or `StartedInPython`) listed first among its bases.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np
import numpy.typing as npt

from gcs.core import rotation
from gcs.core.estimators.base import GpsAcceleration
from gcs.core.estimators.kernels import (
    ACCEL_NORM,
    BACK,
    DISTURBED,
    DUPLICATE,
    DUPLICATES,
    FIRST,
    GPS_A,
    GPS_COURSE,
    GPS_SPEED,
    GPS_T,
    GPS_TIMEOUT,
    GPS_VEL,
    LEARNED,
    OFFSET,
    REINIT_COUNT,
    RELEARNED,
    STEP,
    T_PREV,
    VALID,
    Q,
    State,
    T,
    attitude_of,
    new_state,
)
from gcs.core.gains import Gain, GainSet
from gcs.core.rotation import Vec3
from gcs.core.samples import GpsSample, ImuSample


def load_gps(s: State, gps: GpsAcceleration) -> None:
    """Copy the GPS acceleration's state (after a fix) for the kernels."""
    s[GPS_T] = math.nan if gps.t is None else gps.t
    if gps.vel is not None:
        s[GPS_VEL : GPS_VEL + 3] = gps.vel
    s[GPS_A : GPS_A + 3] = gps.accel
    s[GPS_SPEED] = gps.ground_speed
    s[GPS_COURSE] = gps.course
    s[GPS_TIMEOUT] = gps.timeout


def reinit_reason(s: State, code: int, max_gap: float) -> str:
    """AttitudeEstimator._check_time's words for a re-initialisation."""
    before, t = float(s[T_PREV]), float(s[T])
    if code == FIRST:
        return "first sample"
    if code == BACK:
        return f"clock went back {before - t:.3f} s at t={t:.3f} s (reboot?)"
    return f"gap of {t - before:.3f} s > max_gap {max_gap:g} s at t={t:.3f} s"


def floats(v: object) -> State:
    """A sample vector as an array for the kernels (it usually is one: numba specialises a kernel
    for another dtype or layout once)."""
    return v if type(v) is np.ndarray else np.asarray(v, dtype=np.float64)


class StateTime:
    """`AttitudeEstimator.t` kept in the kernel state (NaN for None)."""

    def __get__(self, est: Compiled, owner: type | None = None) -> float | None:
        t = float(est.s[T])
        return None if math.isnan(t) else t

    def __set__(self, est: Compiled, value: float | None) -> None:
        est.s[T] = math.nan if value is None else value


class StateCount:
    """A counter of `AttitudeEstimator` kept in the kernel state."""

    def __init__(self, slot: int) -> None:
        self.slot = slot

    def __get__(self, est: Compiled, owner: type | None = None) -> int:
        return int(est.s[self.slot])

    def __set__(self, est: Compiled, value: int) -> None:
        est.s[self.slot] = value


@dataclass(frozen=True)
class Kernels:
    """How the whole-run loop (whole.py) drives an estimator: which of its step kernels (STEPS),
    the state slot that says the attitude is valid, and the one that counts `hist`'s rows in use
    (-1: no history to grow)."""

    step: int
    valid_slot: int = VALID
    hist_n_slot: int = -1


class Compiled:
    """What every compiled estimator adds to its reference class (listed first among its bases):
    the kernel state `s` (and `hist`, a velocity history only `ekf` uses), the time policy's
    figures kept in it, and the gains as a vector."""

    KERNELS: ClassVar[Kernels]
    #: the estimator's step kernel: step(s, hist, g, t, gyro, accel, mag, has_mag) -> code
    STEP: ClassVar[Callable[..., int]]
    s: State
    hist: State
    t = StateTime()
    reinit_count = StateCount(REINIT_COUNT)
    duplicates = StateCount(DUPLICATES)
    gains: GainSet
    GAINS: ClassVar[tuple[Gain, ...]]

    def _compiled_state(self, size: int) -> None:
        """Called first in the subclass's __init__: the reference's __init__ writes into it."""
        self.s = new_state(size)
        self.s[Q] = 1.0
        self._quat_view = self.s[Q : Q + 4]
        self.hist = np.zeros((1, 4))
        self._no_mag = np.zeros(3)
        self._g = np.zeros(0)
        self._g_version = -1

    def gain_vector(self) -> State:
        """The gains as a float64 vector in GAINS order, rebuilt only after a change."""
        gains = self.gains
        if self._g_version != gains.version:
            values = gains.values
            self._g = np.array([values[g.name] for g in self.GAINS])
            self._g_version = gains.version
        return self._g

    def update_imu(self, sample: ImuSample) -> bool:
        """The reference's update_imu: the step kernel, then Python only when it asks."""
        n = self.KERNELS.hist_n_slot
        if n >= 0 and self.s[n] >= len(self.hist) - 1:  # room for one more row: grow
            self._grow()
        mag = sample.mag
        code = self.STEP(
            self.s, self.hist, self.gain_vector(), sample.t, floats(sample.gyro), floats(sample.accel),
            self._no_mag if mag is None else floats(mag), mag is not None,
        )  # fmt: skip
        return True if code == STEP else self._after_step(code, sample)

    @property
    def quaternion(self) -> State:
        """The attitude (w, x, y, z), a copy."""
        return self._quat_view.copy()

    def attitude(self) -> tuple[rotation.Quat, Vec3]:
        """AttitudeEstimator.attitude in one compiled call (the same angles, bit for bit)."""
        return attitude_of(self.s)

    def _after_step(self, code: int, sample: ImuSample) -> bool:
        """What update_imu does after the kernel's step returned code: whether the attitude is
        valid, after re-initialising from the sample when the code asks for it."""
        raise NotImplementedError

    def _grow(self) -> None:
        """Make room in `hist` for one more row (only estimators with a history have to)."""
        raise NotImplementedError


class StartedInPython(Compiled):
    """What `dcm`'s and `kf`'s compiled classes share: the validity in slot VALID, GPS fixes
    through the reference's `GpsAcceleration` (then loaded into the state), and a start or
    restart from the sample in Python (`_start`), as their references do."""

    gps: GpsAcceleration
    last_reinit: str
    _start_force: Callable[[float, npt.ArrayLike, npt.ArrayLike, bool], npt.NDArray[np.float64] | None]
    force_carried: bool

    @property
    def valid(self) -> bool:
        return bool(self.s[VALID])

    @valid.setter
    def valid(self, value: bool) -> None:
        self.s[VALID] = float(value)

    def update_gps(self, sample: GpsSample) -> None:
        self.gps.update(sample)
        load_gps(self.s, self.gps)

    def _after_step(self, code: int, sample: ImuSample) -> bool:
        s = self.s
        if code == STEP:
            return True
        if code == DUPLICATE:
            return bool(s[VALID])
        self.last_reinit = reinit_reason(s, code, self.gains["max_gap"])
        if s[ACCEL_NORM] < 1e-6:  # no direction to start from: wait for the next sample
            s[T] = math.nan
            return bool(s[VALID])
        force = self._start_force(sample.t, sample.gyro, sample.accel, sample.mag is not None)
        if force is None:
            s[T] = math.nan
            self.reinit_count -= 1
            return bool(s[VALID])
        self._start(replace(sample, accel=force))
        return True

    def _start(self, sample: ImuSample) -> None:
        """The reference's initialisation from `sample`, on the kernel state; sets VALID."""
        raise NotImplementedError


class MagView:
    """MagneticHeading's health figures, read from a kernel state."""

    def __init__(self, s: State) -> None:
        self.s = s

    @property
    def disturbed(self) -> bool:
        return bool(self.s[DISTURBED])

    @property
    def offset(self) -> tuple[float, float, float]:
        o = self.s[OFFSET : OFFSET + 3].tolist()
        return o[0], o[1], o[2]

    @property
    def relearned(self) -> int:
        return int(self.s[RELEARNED])

    @property
    def offsets_learned(self) -> int:
        return int(self.s[LEARNED])
