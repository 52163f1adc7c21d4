"""Truth motion scripts: where the simulated vehicle really is, how it is oriented and moving.

Every script is an analytic function of vehicle time t (s), so the body rates are the exact
derivative of the attitude and the acceleration the exact derivative of the velocity; a ground
estimator fed perfect sensors must reproduce the truth. All scripts loop forever.

- `bench`   the seed 000 bench tests (§4.2): roll −30/−45/−60°, pitch +30/+45/+60°, yaw −30/−45/+60°.
- `circuit` the seed 000 ground-vehicle circuit (§4.3): side slope (roll ±22°), bump (pitch ∓16°), 90° turns.
- `quad`    take-off, two coordinated circles at 8 m/s (tan φ = v²/(r g)), landing.

Frames and units as docs/design.md: NED metres from the home point, body FRD, q body→NED, rad.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from gcs.core.rotation import euler_to_quat

#: Standard gravity (m/s²), the value ArduPilot uses (GRAVITY_MSS).
GRAVITY = 9.80665


@dataclass(frozen=True, slots=True)
class Truth:
    """The true state at vehicle time t (s).

    q: unit quaternion (w, x, y, z), body FRD → NED.  euler: (roll, pitch, yaw) rad, Z-Y-X.
    omega_body: body angular rate (rad/s, FRD).  accel_ned, vel_ned: m/s², m/s.
    pos: NED metres from the home point (z down, so altitude above home is −pos[2]).
    specific_force: what a perfect accelerometer reads, f = Rᵀ(a − g) in m/s², body FRD
    (−9.81 on z when level and still).  rotation: R body→NED, 3×3.
    """

    t: float
    q: npt.NDArray[np.float64]
    euler: tuple[float, float, float]
    omega_body: npt.NDArray[np.float64]
    accel_ned: npt.NDArray[np.float64]
    vel_ned: npt.NDArray[np.float64]
    pos: npt.NDArray[np.float64]
    specific_force: npt.NDArray[np.float64]
    rotation: npt.NDArray[np.float64]


def euler_matrix(roll: float, pitch: float, yaw: float) -> npt.NDArray[np.float64]:
    """R = Rz(yaw) Ry(pitch) Rx(roll) (body→NED) straight from Z-Y-X Euler angles."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array(
        [
            [cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy],
            [cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy],
            [-sp, sr * cp, cr * cp],
        ]
    )


def body_rates(roll: float, pitch: float, roll_rate: float, pitch_rate: float, yaw_rate: float):
    """Body rates (p, q, r) in rad/s from Z-Y-X Euler angles and their time derivatives."""
    sr, cr = math.sin(roll), math.cos(roll)
    sp, cp = math.sin(pitch), math.cos(pitch)
    return (
        roll_rate - yaw_rate * sp,
        pitch_rate * cr + yaw_rate * sr * cp,
        -pitch_rate * sr + yaw_rate * cr * cp,
    )


def make_truth(t, roll, pitch, yaw, roll_rate, pitch_rate, yaw_rate, pos, vel, acc) -> Truth:
    """Assemble a Truth from Euler angles, their rates and the NED translation state."""
    R = euler_matrix(roll, pitch, yaw)
    acc = np.asarray(acc, dtype=float)
    specific_force = R.T @ (acc - np.array([0.0, 0.0, GRAVITY]))
    return Truth(
        t=t,
        q=euler_to_quat(roll, pitch, yaw),
        euler=(roll, pitch, math.atan2(math.sin(yaw), math.cos(yaw))),
        omega_body=np.array(body_rates(roll, pitch, roll_rate, pitch_rate, yaw_rate)),
        accel_ned=acc,
        vel_ned=np.asarray(vel, dtype=float),
        pos=np.asarray(pos, dtype=float),
        specific_force=specific_force,
        rotation=R,
    )


# --- smooth one-dimensional profiles -----------------------------------------------------------


def min_jerk(u: float) -> tuple[float, float, float, float]:
    """Minimum-jerk blend s(u) = 10u³ − 15u⁴ + 6u⁵ on u in [0, 1] and its 1st–3rd derivatives
    in u. Velocity and acceleration are zero at both ends, so chained segments are smooth."""
    u = min(max(u, 0.0), 1.0)
    u2 = u * u
    return (
        u2 * u * (10 - 15 * u + 6 * u2),
        30 * u2 * (1 - 2 * u + u2),
        60 * u * (1 - 3 * u + 2 * u2),
        60 * (1 - 6 * u + 6 * u2),
    )


class Keyframes:
    """A scalar that moves between keyframe values with minimum-jerk blends and holds between.

    keys: (time s, value) pairs, times strictly increasing; consecutive equal values are a hold.
    `at(t)` returns (value, d/dt, d²/dt², d³/dt³), clamped to the first/last value outside.
    """

    def __init__(self, keys: list[tuple[float, float]]) -> None:
        self.times = [k[0] for k in keys]
        self.values = [k[1] for k in keys]
        if any(b <= a for a, b in zip(self.times, self.times[1:])):
            raise ValueError("keyframe times must increase")

    @property
    def end(self) -> float:
        return self.times[-1]

    def at(self, t: float) -> tuple[float, float, float, float]:
        i = bisect.bisect_right(self.times, t) - 1
        if i < 0:
            return self.values[0], 0.0, 0.0, 0.0
        if i >= len(self.times) - 1:
            return self.values[-1], 0.0, 0.0, 0.0
        t0, t1 = self.times[i], self.times[i + 1]
        a, b = self.values[i], self.values[i + 1]
        if a == b:
            return a, 0.0, 0.0, 0.0
        T = t1 - t0
        s, ds, dds, ddds = min_jerk((t - t0) / T)
        d = b - a
        return a + d * s, d * ds / T, d * dds / (T * T), d * ddds / (T * T * T)


def timeline(start: float, steps: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Keyframes from (duration s, value reached at its end) steps, starting at 0 at `start`."""
    keys = [(0.0, start)]
    t = 0.0
    for duration, value in steps:
        t += duration
        keys.append((t, value))
    return keys


def there_and_back(duration: float, first: float, second: float) -> list[tuple[float, float]]:
    """Timeline steps filling `duration`: level, to `first` and held, level, to `second` and held,
    level again (a side slope one way then the other, or a dip then a rise)."""
    shape = [(0.2, 0.0), (0.1, first), (0.1, first), (0.1, 0.0), (0.1, second), (0.1, second), (0.1, 0.0), (0.2, 0.0)]
    return [(fraction * duration, value) for fraction, value in shape]


# --- scripts -----------------------------------------------------------------------------------


class Script:
    """A looping truth trajectory. Subclasses define `period` (s) and `_state(t)` on [0, period):
    (roll, pitch, yaw, roll_rate, pitch_rate, yaw_rate, pos, vel, acc), SI units, NED."""

    name: str
    period: float

    def truth(self, t: float) -> Truth:
        return make_truth(t, *self._state(math.fmod(t, self.period)))

    def _state(self, t: float) -> tuple:
        raise NotImplementedError


class BenchScript(Script):
    """The seed 000 bench tests: the board on a platform, turned about one axis at a time.

    Each target is reached over `move` s with a minimum-jerk blend (the thesis turned "gradually"),
    held for `hold` s, undone, and followed by a `rest` s pause level. Position never changes.
    """

    name = "bench"
    ROLL_TARGETS_DEG = (-30.0, -45.0, -60.0)
    PITCH_TARGETS_DEG = (30.0, 45.0, 60.0)
    YAW_TARGETS_DEG = (-30.0, -45.0, 60.0)

    def __init__(self, move: float = 3.0, hold: float = 5.0, rest: float = 2.0) -> None:
        def sweep(targets):
            steps = [(rest, 0.0)]
            for deg in targets:
                steps += [(move, math.radians(deg)), (hold, math.radians(deg)), (move, 0.0), (rest, 0.0)]
            return steps

        block = sum(d for d, _ in sweep(self.ROLL_TARGETS_DEG))
        roll = sweep(self.ROLL_TARGETS_DEG) + [(2 * block, 0.0)]
        pitch = [(block, 0.0)] + sweep(self.PITCH_TARGETS_DEG) + [(block, 0.0)]
        yaw = [(2 * block, 0.0)] + sweep(self.YAW_TARGETS_DEG)
        self.roll = Keyframes(timeline(0.0, roll))
        self.pitch = Keyframes(timeline(0.0, pitch))
        self.yaw = Keyframes(timeline(0.0, yaw))
        self.period = 3 * block

    def _state(self, t: float) -> tuple:
        r, dr, _, _ = self.roll.at(t)
        p, dp, _, _ = self.pitch.at(t)
        y, dy, _, _ = self.yaw.at(t)
        zero = (0.0, 0.0, 0.0)
        return r, p, y, dr, dp, dy, zero, zero, zero


class CircuitScript(Script):
    """The seed 000 ground-vehicle circuit: a car driving a closed rounded rectangle.

    The car moves along its body x axis at `speed` m/s, so v_ned = speed · (cosθ cosψ, cosθ sinψ,
    −sinθ) and a_ned = speed · d/dt of that direction (analytic). Zones as in the thesis (Fig. 14):
    a side slope on each short side (roll +22° then −22°), a bump on each long side (pitch −16° then
    +16°: zero net climb, so the loop closes), and four 90° right turns. Position is the velocity
    integrated once at construction on a fine grid (the only non-analytic quantity; error ~1e-9 m).
    """

    name = "circuit"

    def __init__(
        self, speed: float = 3.0, long_side: float = 40.0, short_side: float = 20.0, turn: float = 6.0
    ) -> None:
        self.speed = speed
        t_long, t_short = long_side / speed, short_side / speed
        bump = there_and_back(t_long, math.radians(-16), math.radians(16))
        slope = there_and_back(t_short, math.radians(22), math.radians(-22))
        heading, pitch, roll = [], [], []
        yaw = 0.0
        for duration, is_long in ((t_long, True), (t_short, False)) * 2:
            heading += [(duration, yaw), (turn, yaw + math.pi / 2)]
            yaw += math.pi / 2
            flat = [(duration, 0.0)]
            pitch += (bump if is_long else flat) + [(turn, 0.0)]
            roll += (flat if is_long else slope) + [(turn, 0.0)]
        self.yaw = Keyframes(timeline(0.0, heading))
        self.pitch = Keyframes(timeline(0.0, pitch))
        self.roll = Keyframes(timeline(0.0, roll))
        self.period = self.yaw.end
        self._build_position_table()

    def _velocity(self, t: float):
        p = self.pitch.at(t)[0]
        y = self.yaw.at(t)[0]
        cp = math.cos(p)
        return (self.speed * cp * math.cos(y), self.speed * cp * math.sin(y), -self.speed * math.sin(p))

    def _build_position_table(self, step: float = 0.005) -> None:
        n = int(math.ceil(self.period / step))
        self._step = self.period / n
        times = np.arange(n + 1) * self._step
        vel = np.array([self._velocity(t) for t in times])
        mid = np.array([self._velocity(t + 0.5 * self._step) for t in times[:-1]])
        # Simpson on each cell: (v0 + 4 v_mid + v1) / 6 · h.
        cells = (vel[:-1] + 4 * mid + vel[1:]) * (self._step / 6.0)
        self._pos = np.vstack([np.zeros(3), np.cumsum(cells, axis=0)])

    def _state(self, t: float) -> tuple:
        r, dr, _, _ = self.roll.at(t)
        p, dp, _, _ = self.pitch.at(t)
        y, dy, _, _ = self.yaw.at(t)
        v = self.speed
        cp, sp, cy, sy = math.cos(p), math.sin(p), math.cos(y), math.sin(y)
        vel = (v * cp * cy, v * cp * sy, -v * sp)
        acc = (v * (-sp * dp * cy - cp * sy * dy), v * (-sp * dp * sy + cp * cy * dy), -v * cp * dp)
        k = min(int(t / self._step), len(self._pos) - 2)
        frac = t / self._step - k
        pos = self._pos[k] + (self._pos[k + 1] - self._pos[k]) * frac
        return r, p, y, dr, dp, dy, pos, vel, acc


class QuadScript(Script):
    """A quadcopter flight whose attitude is what its thrust and heading require.

    The translation is analytic to the third derivative: a minimum-jerk climb to `altitude` m, then
    `laps` circles of radius `radius` m (speed ramped 0 → `speed` → 0 m/s with minimum-jerk blends),
    then descent and landing. The heading follows the course. The thrust axis (−body z) is along
    −f with f = a − g, so in a steady turn tan φ = v²/(r g) and the specific force has no body-y
    component; accelerating forward pitches the nose down. Euler rates come from the jerk.
    """

    name = "quad"

    def __init__(
        self,
        speed: float = 8.0,
        radius: float = 20.0,
        laps: int = 2,
        altitude: float = 10.0,
        climb: float = 6.0,
        ramp: float = 4.0,
        idle: float = 2.0,
        hover: float = 2.0,
    ) -> None:
        self.speed, self.radius, self.ramp = speed, radius, ramp
        cruise = 2 * math.pi * radius * laps / speed - ramp  # ramps cover speed·ramp/2 each
        if cruise < 0:
            raise ValueError("circle too short for the speed ramps")
        self.t_go = idle + climb + hover
        self.t_cruise = self.t_go + ramp
        self.t_brake = self.t_cruise + cruise
        t_stop = self.t_brake + ramp
        self.height = Keyframes(
            [
                (0.0, 0.0),
                (idle, 0.0),
                (idle + climb, altitude),
                (t_stop + hover, altitude),
                (t_stop + hover + climb, 0.0),
            ]
        )
        self.period = self.height.end + idle

    def _arc(self, t: float) -> tuple[float, float, float, float]:
        """Arc length s (m) along the circle and its 1st–3rd time derivatives."""
        V, T = self.speed, self.ramp
        if t <= self.t_go:
            return 0.0, 0.0, 0.0, 0.0
        if t < self.t_cruise:
            u = (t - self.t_go) / T
            s, ds, dds, _ = min_jerk(u)
            return V * T * u**4 * (2.5 - 3 * u + u * u), V * s, V * ds / T, V * dds / (T * T)
        if t < self.t_brake:
            return V * T / 2 + V * (t - self.t_cruise), V, 0.0, 0.0
        base = V * T / 2 + V * (self.t_brake - self.t_cruise)
        u = min((t - self.t_brake) / T, 1.0)
        s, ds, dds, _ = min_jerk(u)
        covered = V * T * (u - u**4 * (2.5 - 3 * u + u * u))  # ∫ V (1 − s(u)) dt
        return base + covered, V * (1 - s), -V * ds / T, -V * dds / (T * T)

    def _state(self, t: float) -> tuple:
        s, v, a_t, j_t = self._arc(t)
        r = self.radius
        alpha = s / r
        ca, sa = math.cos(alpha), math.sin(alpha)
        h, dh, ddh, dddh = self.height.at(t)
        # Circle through home, starting northbound and turning right (clockwise from above).
        pos = (r * sa, r * (1 - ca), -h)
        vel = (v * ca, v * sa, -dh)
        a_n = v * v / r  # centripetal
        acc = (a_t * ca - a_n * sa, a_t * sa + a_n * ca, -ddh)
        jt, jn = j_t - v**3 / (r * r), 3 * v * a_t / r
        jerk = (jt * ca - jn * sa, jt * sa + jn * ca, -dddh)
        yaw, yaw_rate = alpha, v / r
        # Specific force in the heading frame (x along course, y to the right).
        fx_n, fy_n, fz = acc[0], acc[1], acc[2] - GRAVITY
        cy, sy = math.cos(yaw), math.sin(yaw)
        fx = cy * fx_n + sy * fy_n
        fy = -sy * fx_n + cy * fy_n
        dfx = cy * jerk[0] + sy * jerk[1] + yaw_rate * fy
        dfy = -sy * jerk[0] + cy * jerk[1] - yaw_rate * fx
        dfz = jerk[2]
        horiz2 = fx * fx + fz * fz
        horiz = math.sqrt(horiz2)
        roll = math.atan2(fy, horiz)
        pitch = math.atan2(-fx, -fz)
        dhoriz = (fx * dfx + fz * dfz) / horiz
        roll_rate = (horiz * dfy - fy * dhoriz) / (horiz2 + fy * fy)
        pitch_rate = (fz * dfx - fx * dfz) / horiz2
        return roll, pitch, yaw, roll_rate, pitch_rate, yaw_rate, pos, vel, acc


SCRIPTS: dict[str, type[Script]] = {"bench": BenchScript, "circuit": CircuitScript, "quad": QuadScript}


def make_script(name: str) -> Script:
    """The named script with its default parameters."""
    try:
        return SCRIPTS[name]()
    except KeyError:
        raise ValueError(f"unknown script {name!r}; choose one of {', '.join(SCRIPTS)}") from None
