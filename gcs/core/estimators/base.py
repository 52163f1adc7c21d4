"""What every attitude estimator offers, so the live pipeline, `gcs estimate`, replay and the
dashboard treat them alike, and the policies they share so they can be compared fairly:

* **Frames.** Samples may be in any right-handed sensor frame (MAVLink's FRD, a z-up IMU, ...). Earth
  is NED, defined by physics only: "down" opposes the specific force at rest, north is the horizontal
  field turned by `declination`; the quaternion rotates sensor → NED.
* **Initialisation** (`initial_attitude`): tilt from the accelerometer, heading from the magnetometer (or 0);
  a start waits up to FIELD_WAIT s for a sample with a field (`_start_force`).
* **Time** (`_check_time`): the vehicle clock. A repeated timestamp is ignored; a clock going back or a
  gap longer than `max_gap` re-initialises the filter, with the reason kept for `health()`.
Details: docs/estimators/common.md
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import ClassVar

import numpy as np
import numpy.typing as npt

from gcs.core.gains import Gain, GainSet
from gcs.core.rotation import Quat, Vec3, quat_to_euler
from gcs.core.samples import G0, GpsSample, ImuSample

#: Settings every estimator declares (append them to your own GAINS).
COMMON_GAINS: tuple[Gain, ...] = (
    Gain("declination", 0.0, -math.pi, math.pi, "rad", "magnetic declination, east positive; output is true north"),
    Gain("max_gap", 0.5, 0.01, 10.0, "s", "an IMU gap longer than this re-initialises the filter"),
)

#: GPS aiding settings shared by the estimators that use `GpsAcceleration`.
GPS_GAINS: tuple[Gain, ...] = (
    Gain("gps_gain", 1.0, 0.0, 1.0, "", "weight of the GPS acceleration removed from the specific force"),
    Gain("gps_speed_min", 3.0, 0.0, 50.0, "m/s", "minimum ground speed to use GPS course for yaw (no usable mag)"),
)

#: Shock and saturation settings shared by every estimator (see `Shock`).
SHOCK_GAINS: tuple[Gain, ...] = (
    Gain("shock_acc", 5.0 * G0, G0, 2000.0, "m/s²", "|specific force| above which a sample is a shock (5 g)"),
    Gain("gyro_limit", math.radians(1800.0), 0.1, 1000.0, "rad/s", "|rate| at which the gyro may be saturated"),
    Gain("shock_hold", 0.5, 0.0, 10.0, "s", "the accelerometer stays ignored this long after a shock"),
)

#: What a gyro sample is, for the estimators that turn by two of them (dcm, kf, ekf): a log's every
#: sample is the mean rate over the interval before it (turn ω₁ dt); a slower stream (RAW_IMU at
#: 25-50 Hz) picks samples, each the rate at its instant (the trapezoid; kf and ekf add the coning term).
PICK_GAINS: tuple[Gain, ...] = (
    Gain("pick_dt", 0.01, 0.0, 10.0, "s", "IMU intervals longer than this are picked samples: trapezoid + coning"),
)

#: s of vehicle time a (re)start waits for a sample with a magnetic field before it starts without
#: one: ArduPilot's first RAW_IMU after a boot carry an all-zero field, its compass not read yet
#: (SITL: 4-5 samples, 80-100 ms), and a heading made up without one (-90° on ArduPlane) took the
#: heading loop seconds to undo. A source with no magnetometer starts this much later.
FIELD_WAIT = 1.0

#: A number or a label in `AttitudeEstimator.health()`; a few are per-axis tuples.
HealthValue = float | str | tuple[float, ...]


def initial_attitude(
    accel: npt.NDArray[np.float64], mag: npt.NDArray[np.float64] | None, declination: float = 0.0
) -> npt.NDArray[np.float64]:
    """Rotation matrix sensor → NED from one specific-force vector and an optional magnetic vector.

    Rows of R are the NED axes seen in the sensor frame (seed 000 eqs. 5-10, as the thesis code
    builds them in Annex A): D = -f/|f|; N = horizontal part of the field, (D × m) × D, normalised;
    E = D × N. Without a usable field the heading is 0: N is the sensor axis closest to
    horizontal, projected. The declination then turns magnetic north into true north.
    """
    f = np.asarray(accel, dtype=float)
    down = -f / np.linalg.norm(f)
    north = None
    if mag is not None:
        h = np.cross(np.cross(down, mag), down)
        if np.linalg.norm(h) > 1e-9:
            north = h / np.linalg.norm(h)
    if north is None:
        axis = np.eye(3)[int(np.argmin(np.abs(down)))]
        h = axis - down * float(axis @ down)
        north = h / np.linalg.norm(h)
    east = np.cross(down, north)
    R: npt.NDArray[np.float64] = np.vstack([north, east, down])
    c, s = math.cos(declination), math.sin(declination)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ R


class AttitudeEstimator(ABC):
    """An attitude filter fed SI samples in time order.

    Subclasses declare `name`, `GAINS` (the tunables, ending with COMMON_GAINS) and `PRESETS`;
    the current values live in `self.gains` and may change between any two samples
    (`set_gain`) without a restart or a jump in the output.
    """

    name: ClassVar[str]
    GAINS: ClassVar[tuple[Gain, ...]]
    PRESETS: ClassVar[dict[str, dict[str, float]]]
    DEFAULT_PRESET: ClassVar[str]

    def __init__(self, preset: str | None = None, **gains: float) -> None:
        self.gains = GainSet(self.GAINS, self.PRESETS)
        self.gains.apply_preset(preset or self.DEFAULT_PRESET)
        self.preset = preset or self.DEFAULT_PRESET
        for name, value in gains.items():
            self.gains.set(name, value)
        self.t: float | None = None  # vehicle time of the last fused IMU sample
        self.reinit_count = 0
        self.last_reinit = ""  # why the filter last (re)initialised
        self.duplicates = 0
        #: a start waiting for a field: the first held sample's time, the last one's, and the first
        #: one's specific force carried to it (`_start_force`)
        self.field_wait: tuple[float, float, npt.NDArray[np.float64]] | None = None
        self.force_carried = False  # whether the last start's force was carried from a held sample

    def set_gain(self, name: str, value: float) -> tuple[float, float]:
        """Validate and apply one gain now; returns (old, new)."""
        return self.gains.set(name, value)

    def _check_time(self, t: float) -> float | None:
        """dt to integrate over, 0.0 for a duplicate (skip it), or None: re-initialise now.

        Sets `last_reinit` and counts re-initialisations; the caller then initialises from the
        sample. `self.t` is advanced for every sample that is not a duplicate.
        """
        if self.t is None:
            reason = "first sample"
        elif t == self.t:
            self.duplicates += 1
            return 0.0
        elif t < self.t:
            reason = f"clock went back {self.t - t:.3f} s at t={t:.3f} s (reboot?)"
        elif t - self.t > self.gains["max_gap"]:
            reason = f"gap of {t - self.t:.3f} s > max_gap {self.gains['max_gap']:g} s at t={t:.3f} s"
        else:
            dt = t - self.t
            self.t = t
            return dt
        self.t = t
        self.reinit_count += 1
        self.last_reinit = reason
        return None

    def _start_force(
        self, t: float, gyro: npt.ArrayLike, accel: npt.ArrayLike, has_field: bool
    ) -> npt.NDArray[np.float64] | None:
        """The specific force to (re)initialise the tilt from at vehicle time t, or None: wait.

        A sample without a magnetic field is held (None) until one with a field comes or FIELD_WAIT
        s have passed since the first held one (a clock going back starts the wait again); a held
        sample starts nothing, and the caller does not count it as a re-initialisation. After a
        wait the tilt is the first held sample's, carried to this sample by the gyro (each held
        sample turns the sensor by ω dt: a fixed earth vector seen from it turns by -ω dt,
        Rodrigues), and the heading is then the field's over that tilt: as AP_AHRS_DCM takes its
        first yaw from the compass over the attitude it already has (`have_initial_yaw`). The
        samples that bring ArduPlane SITL's first field carry a boot jolt of 0.3 g along x, which
        as gravity would be 17° of pitch and 34° of heading (so `dcm` and `kf` then also start
        their averaged specific force at the carried one: `force_carried`).
        """
        f = np.array(accel, dtype=float)
        held = self.field_wait
        if held is not None and t >= held[0]:
            t0, t_prev, f = held
            wx, wy, wz = (float(v) * (t - t_prev) for v in np.asarray(gyro, dtype=float))
            angle = math.sqrt(wx * wx + wy * wy + wz * wz)
            if angle > 0.0:
                k = np.array([wx, wy, wz]) / angle
                kf = np.cross(k, f)
                f = f - math.sin(angle) * kf + (1.0 - math.cos(angle)) * np.cross(k, kf)
        else:
            t0 = t
        if has_field or t - t0 >= FIELD_WAIT:
            self.force_carried, self.field_wait = held is not None, None
            return f
        self.field_wait = (t0, t, f)
        return None

    def _common_health(self) -> dict[str, HealthValue]:
        return {"reinit_count": self.reinit_count, "last_reinit": self.last_reinit, "duplicates": self.duplicates}

    @abstractmethod
    def update_imu(self, sample: ImuSample) -> bool:
        """Advance to sample.t and fuse it. Returns True once the attitude is valid."""

    def update_gps(self, sample: GpsSample) -> None:  # noqa: B027 - a no-op default on purpose
        """Fuse a GPS fix (velocity/course aiding). Estimators that ignore GPS keep this."""

    @property
    @abstractmethod
    def quaternion(self) -> npt.NDArray[np.float64]:
        """Current attitude, unit quaternion (w, x, y, z), sensor/body → earth NED."""

    def attitude(self) -> tuple[Quat, Vec3]:
        """The quaternion as plain floats and its Z-Y-X angles (rad), as the live pipeline reads
        them after every sample (non-finite when the state is)."""
        q = self.quaternion.tolist()
        w, x, y, z = q
        return (w, x, y, z), quat_to_euler(q)

    @abstractmethod
    def health(self) -> dict[str, HealthValue]:
        """Numbers that tell whether to trust the output (accel norm, innovations, ...)."""


class Shock:
    """A hard touch-down, a tap or a saturated gyro: |f| > `shock_acc` or |ω| > `gyro_limit`
    (0.9 of a 2000°/s full scale by default). While `active` (the sample and `shock_hold` s after)
    the estimators ignore the accelerometer, which then measures the impact and not gravity; a
    saturated gyro (`saturated`) has integrated too little turn, so the heading is no longer
    trusted over the magnetometer (docs/estimators/common.md).
    """

    def __init__(self) -> None:
        self.until = -math.inf
        self.active = False
        self.saturated = False
        self.count = 0

    def update(self, t: float, accel_norm: float, spin: float, g: Mapping[str, float]) -> bool:
        """Whether the accelerometer is to be ignored at vehicle time t."""
        self.saturated = spin > g["gyro_limit"]
        if accel_norm > g["shock_acc"] or self.saturated:
            if t >= self.until:
                self.count += 1
            self.until = t + g["shock_hold"]
        self.active = t <= self.until
        return self.active


class GpsAcceleration:
    """Earth-frame (NED) acceleration from successive GPS velocities, for removing linear and
    centripetal acceleration from the specific force (Premerlani, "RollPitchDriftCompensation",
    the "equation 9" of AP_AHRS_DCM): a = (v_k - v_{k-1}) / (t_k - t_{k-1}).

    It is held between fixes and dropped (zero) when the last fix is older than `timeout`, when
    a fix has no velocity or no 3-D fix, or when fixes are out of order. Repeated fixes (same t)
    are ignored. The vertical component stays 0 when the source has no vertical speed.
    """

    def __init__(self, timeout: float = 1.0) -> None:
        self.timeout = timeout
        self.reset()

    def reset(self) -> None:
        self.t: float | None = None
        self.vel: npt.NDArray[np.float64] | None = None
        self.accel = np.zeros(3)
        self.ground_speed = 0.0
        self.course = math.nan

    def update(self, sample: GpsSample) -> None:
        if self.t is not None and sample.t <= self.t:
            if sample.t < self.t:  # clock went back: start over
                self.reset()
            return
        if sample.vel_ned is None or sample.fix_type < 3:
            self.reset()
            return
        vel = np.asarray(sample.vel_ned, dtype=float)
        if self.vel is not None and self.t is not None and sample.t - self.t <= self.timeout:
            self.accel = (vel - self.vel) / (sample.t - self.t)
        else:
            self.accel = np.zeros(3)
        self.t, self.vel = sample.t, vel
        self.ground_speed, self.course = sample.ground_speed, sample.course

    def at(self, t: float) -> tuple[float, float, float]:
        """The held acceleration (NED, m/s²) if the last fix is recent at vehicle time t, else zeros."""
        if self.t is None or abs(t - self.t) > self.timeout:
            return 0.0, 0.0, 0.0
        a = self.accel
        return float(a[0]), float(a[1]), float(a[2])

    def course_at(self, t: float, speed_min: float) -> float | None:
        """Course over ground (rad, true) if recent and the ground speed is at least speed_min."""
        if self.t is None or abs(t - self.t) > self.timeout or not self.ground_speed >= speed_min:
            return None
        return self.course if math.isfinite(self.course) else None
