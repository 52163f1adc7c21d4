"""Guided bench-test protocols: the steps, hold detection, and the seeds' figures of merit.

A protocol is a list of steps, each one known angle on one axis held for a while (seed 000 §4.2:
roll −30/−45/−60°, pitch +30/+45/+60°, yaw −30/−45/+60°). `HoldDetector` says when a step's
hold is complete on a live attitude series; `step_metrics` scores every source over the step's
recorded window against the target, with seed 000's mean relative error over the last 22
samples (and over the whole hold), the absolute error, seed 004's MSE per axis, rise and
settling time and the cross-axis disturbance; `protocol_tables` makes seed 000's per-axis means
and seed 004's MSE table with the reduction relative to the raw accelerometer/magnetometer
angles (`accel_mag_series`). Every definition, with its source: docs/protocols.md.
Pure computation: series in, typed results out, the same numbers live and from a session.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from gcs.core.estimators.kf import accel_tilt, mag_heading

AXES = ("roll", "pitch", "yaw")
#: The name under which the raw accelerometer/magnetometer angles enter the tables.
ACCEL_MAG = "accel_mag"
#: N×4 attitude series: t (vehicle s), roll, pitch, yaw (rad), in time order.
Series = npt.NDArray[np.float64]


class ProtocolError(ValueError):
    """A protocol file that cannot be used; the message names the field."""


@dataclass(frozen=True, slots=True)
class Step:
    """Turn `axis` to `target_deg` and hold it within `tolerance_deg` for `hold_s` seconds."""

    axis: str
    target_deg: float
    hold_s: float
    tolerance_deg: float
    label: str = ""
    #: the attitude of the axes not under test during this step (None: the protocol's)
    level_deg: tuple[float, float, float] | None = None

    @property
    def name(self) -> str:
        return self.label or f"{self.axis} {self.target_deg:+g}"

    @property
    def prompt(self) -> str:
        hold = f"{self.hold_s:g} s within ±{self.tolerance_deg:g}°"
        return f"rotate to {self.axis} {self.target_deg:+g}° and hold ({hold})"


@dataclass(frozen=True, slots=True)
class Protocol:
    """A test protocol. `level_deg` is the attitude of the axes not under test (the bench at rest),
    the reference of their MSE; `detect_source` the source whose attitude detects a hold;
    `last_samples` seed 000's 22; `settle_band_pct` the settling band in % of the step's change."""

    name: str
    steps: tuple[Step, ...]
    description: str = ""
    level_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    detect_source: str = "onboard"
    last_samples: int = 22
    settle_band_pct: float = 5.0

    def reference_deg(self, step: Step) -> tuple[float, float, float]:
        """The attitude a perfect source shows during the step's hold (degrees)."""
        ref = list(step.level_deg or self.level_deg)
        ref[AXES.index(step.axis)] = step.target_deg
        return ref[0], ref[1], ref[2]

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON-able form (what the session's protocol event keeps); `protocol_from_dict` reads it."""
        return asdict(self)


def protocol_from_dict(data: Mapping[str, Any], name: str | None = None) -> Protocol:
    """A Protocol from parsed TOML or `Protocol.as_dict()`; ProtocolError names the bad field."""
    defaults = data.get("defaults", {})
    if not isinstance(defaults, Mapping):
        raise ProtocolError("[defaults] must be a table")
    raw_steps = data.get("steps")
    if not isinstance(raw_steps, list) or not raw_steps:
        raise ProtocolError("needs at least one [[steps]] entry")
    steps = []
    for i, raw in enumerate(raw_steps, start=1):
        if not isinstance(raw, Mapping):
            raise ProtocolError(f"step {i}: must be a table")
        merged = {**defaults, **raw}
        unknown = set(merged) - {"axis", "target_deg", "hold_s", "tolerance_deg", "label", "level_deg"}
        if unknown:
            raise ProtocolError(f"step {i}: unknown field {sorted(unknown)[0]!r}")
        axis = merged.get("axis")
        if axis not in AXES:
            raise ProtocolError(f"step {i}: axis must be one of {', '.join(AXES)}, not {axis!r}")
        try:
            step = Step(
                axis=axis,
                target_deg=_number(merged, "target_deg"),
                hold_s=_number(merged, "hold_s", positive=True),
                tolerance_deg=_number(merged, "tolerance_deg", positive=True),
                label=str(merged.get("label", "")),
                level_deg=None if merged.get("level_deg") is None else _attitude(merged, "level_deg"),
            )
        except ProtocolError as exc:
            raise ProtocolError(f"step {i}: {exc}") from None
        if step.target_deg == 0.0:
            raise ProtocolError(f"step {i}: target_deg 0 has no relative error (seed 000 divides by it)")
        steps.append(step)
    last = data.get("last_samples", 22)
    if not isinstance(last, int) or last < 1:
        raise ProtocolError("last_samples must be a positive integer")
    return Protocol(
        name=str(data.get("name", name or "protocol")),
        steps=tuple(steps),
        description=str(data.get("description", "")),
        level_deg=_attitude(data, "level_deg", (0.0, 0.0, 0.0)),
        detect_source=str(data.get("detect_source", "onboard")),
        last_samples=last,
        settle_band_pct=_number(data, "settle_band_pct", positive=True, default=5.0),
    )


def parse_protocol(text: str, name: str) -> Protocol:
    """A protocol from the text of a TOML file (format: docs/protocols.md)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ProtocolError(f"not valid TOML: {exc}") from None
    return protocol_from_dict(data, name)


def _attitude(data: Mapping[str, Any], key: str, default: Any = None) -> tuple[float, float, float]:
    value = data.get(key, default)
    if not isinstance(value, list | tuple) or len(value) != 3 or not all(_is_number(v) for v in value):
        raise ProtocolError(f"{key} must be [roll, pitch, yaw] in degrees, not {value!r}")
    return float(value[0]), float(value[1]), float(value[2])


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _number(data: Mapping[str, Any], key: str, positive: bool = False, default: float | None = None) -> float:
    value = data.get(key, default)
    if not _is_number(value):
        raise ProtocolError(f"{key} must be a number, not {value!r}")
    if positive and value <= 0:
        raise ProtocolError(f"{key} must be positive, not {value!r}")
    return float(value)


# --- hold detection ------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class StepWindow:
    """One completed step: prompted at `t_start`, held from `t_hold_start` to `t_hold_end`
    (vehicle s). `attempt` counts repeats (1 = first)."""

    index: int
    attempt: int
    t_start: float
    t_hold_start: float
    t_hold_end: float


#: A gap in the detecting source longer than this (s) restarts a hold: it must be seen held.
HOLD_MAX_GAP = 0.5


class HoldDetector:
    """Feed one source's attitude in time order; `feed` returns (hold start, hold end) once the
    step's axis has been seen within the tolerance of the target for the hold time, with no
    gap in the samples longer than HOLD_MAX_GAP (lost packets hide what happened)."""

    def __init__(self, step: Step) -> None:
        self.axis = AXES.index(step.axis)
        self.target = math.radians(step.target_deg)
        self.tolerance = math.radians(step.tolerance_deg)
        self.hold = step.hold_s
        self.since: float | None = None
        self.last_t = -math.inf

    def feed(self, t: float, angles: tuple[float, float, float]) -> tuple[float, float] | None:
        if t <= self.last_t:
            return None
        gap = t - self.last_t > HOLD_MAX_GAP
        self.last_t = t
        error = abs(math.remainder(angles[self.axis] - self.target, math.tau))
        if error > self.tolerance or gap:
            self.since = None if error > self.tolerance else t
            return None
        if self.since is None:
            self.since = t
        return (self.since, t) if t - self.since >= self.hold else None


# --- metrics -------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class SourceMetrics:
    """One source over one step, against the target. Angles in degrees, times in s, NaN where a
    figure cannot be had (too few samples, a source that never reached the target)."""

    source: str
    step: int  # 1-based step number in the protocol
    label: str
    axis: str
    target_deg: float
    n_hold: int  # samples of the source in the hold window
    mre_last_pct: float  # seed 000: mean |x − target| / |target| over the last `last_samples`, %
    mre_hold_pct: float  # the same over the whole hold
    abs_err_last_deg: float  # mean |x − target| over the last samples
    abs_err_hold_deg: float
    mse_roll: float  # seed 004: mean squared error against the step's reference attitude, deg²
    mse_pitch: float
    mse_yaw: float
    rise_s: float  # 10 % → 90 % of the change from the level attitude to the target
    settling_s: float  # from the 10 % crossing until it stays within the settling band
    cross_deg: float  # largest excursion of the two other axes from their value at the 10 % crossing

    def mse(self) -> tuple[float, float, float]:
        return self.mse_roll, self.mse_pitch, self.mse_yaw


#: The columns of a SourceMetrics row, in order (CSV, .mat and the HTML table use them).
METRIC_FIELDS = tuple(SourceMetrics.__dataclass_fields__)


def _slice(series: Series, t0: float, t1: float) -> Series:
    lo = int(np.searchsorted(series[:, 0], t0, side="left"))
    hi = int(np.searchsorted(series[:, 0], t1, side="right"))
    return series[lo:hi]


def step_metrics(protocol: Protocol, window: StepWindow, source: str, series: Series) -> SourceMetrics | None:
    """Score one source over one step window; None when it has no sample in the hold."""
    step = protocol.steps[window.index]
    k = AXES.index(step.axis)
    hold = _slice(series, window.t_hold_start, window.t_hold_end)
    if not len(hold):
        return None
    ref = np.radians(protocol.reference_deg(step))
    err = np.degrees(np.remainder(hold[:, 1:4] - ref + math.pi, math.tau) - math.pi)  # wrapped, deg
    axis_err = np.abs(err[:, k])
    last = axis_err[-protocol.last_samples :]
    target = abs(step.target_deg)
    mse = np.mean(err**2, axis=0)
    run = _slice(series, window.t_start, window.t_hold_end)
    rise, settling, cross = _dynamics(protocol, step, run, window.t_hold_start)
    return SourceMetrics(
        source=source,
        step=window.index + 1,
        label=step.name,
        axis=step.axis,
        target_deg=step.target_deg,
        n_hold=len(hold),
        mre_last_pct=float(100.0 * np.mean(last) / target),
        mre_hold_pct=float(100.0 * np.mean(axis_err) / target),
        abs_err_last_deg=float(np.mean(last)),
        abs_err_hold_deg=float(np.mean(axis_err)),
        mse_roll=float(mse[0]),
        mse_pitch=float(mse[1]),
        mse_yaw=float(mse[2]),
        rise_s=rise,
        settling_s=settling,
        cross_deg=cross,
    )


def _dynamics(protocol: Protocol, step: Step, run: Series, t_hold: float) -> tuple[float, float, float]:
    """Rise time, settling time and cross-axis disturbance of one step run (prompt → hold end).

    The step is the change from the level attitude to the target; the operator may first have to
    come back from the previous step, so the motion starts at the last 10 % crossing before the
    hold. Rise: 10 % → 90 %; settling: 10 % crossing → inside the band for good; cross-axis:
    largest excursion of the two other axes from their value at the 10 % crossing."""
    k = AXES.index(step.axis)
    level = (step.level_deg or protocol.level_deg)[k]
    angles = np.degrees(run[:, 1:4])
    x = np.remainder(angles[:, k] - level + 180.0, 360.0) - 180.0
    change = math.remainder(step.target_deg - level, 360.0)
    before = int(np.searchsorted(run[:, 0], t_hold, side="left"))
    if len(run) < 2 or abs(change) < 1e-9 or before < 1:
        return math.nan, math.nan, math.nan
    progress = x / change
    low = np.nonzero(progress[:before] < 0.1)[0]
    i10 = int(low[-1]) + 1 if len(low) else 0
    t = run[i10:, 0]
    t10 = float(t[0])
    t90 = _first(t, progress[i10:] >= 0.9)
    band = abs(change) * protocol.settle_band_pct / 100.0
    outside = np.nonzero(np.abs(x[i10:] - change) > band)[0]
    if not len(outside):
        settling = 0.0
    elif outside[-1] == len(t) - 1:
        settling = math.nan  # never settled
    else:
        settling = float(t[outside[-1] + 1] - t10)
    others = [i for i in range(3) if i != k]
    drift = np.remainder(angles[i10:, others] - angles[i10, others] + 180.0, 360.0) - 180.0
    return t90 - t10, settling, float(np.max(np.abs(drift)))


def _first(t: npt.NDArray[np.float64], mask: npt.NDArray[np.bool_]) -> float:
    hits = np.nonzero(mask)[0]
    return float(t[hits[0]]) if len(hits) else math.nan


def accel_mag_series(imu: npt.NDArray[np.float64], declination: float = 0.0) -> Series:
    """The raw sensors' own attitude: roll and pitch from the specific force alone, heading from
    the tilt-compensated magnetometer (seed 004's "IMU measurement", before any filter).
    imu: N×10 (t, gyro xyz, accel xyz, mag xyz), as the session's IMU table; yaw NaN without a field."""
    out = np.full((len(imu), 4), math.nan)
    for i, row in enumerate(imu.tolist()):
        roll, pitch = accel_tilt(row[4:7])
        mag = row[7:10]
        heading = None if any(math.isnan(v) for v in mag) else mag_heading(mag, roll, pitch, declination)
        out[i] = (row[0], roll, pitch, math.nan if heading is None else heading)
    return out


# --- tables --------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class AxisMean:
    """Seed 000's summary: the mean over a source's steps on one axis of the mean relative error."""

    source: str
    axis: str
    steps: int
    mre_last_pct: float
    mre_hold_pct: float
    abs_err_last_deg: float


@dataclass(frozen=True, slots=True)
class MseRow:
    """Seed 004's Table 5.4 for one source: MSE per axis over every hold (deg²) and its reduction
    relative to the raw accelerometer/magnetometer angles, % (positive: the source is better)."""

    source: str
    samples: int
    mse_roll: float
    mse_pitch: float
    mse_yaw: float
    reduction_roll_pct: float
    reduction_pitch_pct: float
    reduction_yaw_pct: float


@dataclass(frozen=True, slots=True)
class ProtocolTables:
    protocol: Protocol
    windows: tuple[StepWindow, ...]
    steps: tuple[SourceMetrics, ...] = field(default=())
    axis_means: tuple[AxisMean, ...] = field(default=())
    mse: tuple[MseRow, ...] = field(default=())


def protocol_tables(protocol: Protocol, windows: list[StepWindow], series: Mapping[str, Series]) -> ProtocolTables:
    """Score every source over every step's latest attempt and summarise as both seeds did.
    `series` holds every source by name, `ACCEL_MAG` among them when the raw sensors are known."""
    latest: dict[int, StepWindow] = {}
    for w in windows:
        latest[w.index] = w  # a repeat replaces the earlier attempt
    chosen = [latest[i] for i in sorted(latest)]
    rows = [
        m for w in chosen for source in series if (m := step_metrics(protocol, w, source, series[source])) is not None
    ]
    means = []
    for source in series:
        for axis in AXES:
            mine = [m for m in rows if m.source == source and m.axis == axis]
            if mine:
                means.append(
                    AxisMean(
                        source,
                        axis,
                        len(mine),
                        float(np.mean([m.mre_last_pct for m in mine])),
                        float(np.mean([m.mre_hold_pct for m in mine])),
                        float(np.mean([m.abs_err_last_deg for m in mine])),
                    )
                )
    pooled: dict[str, tuple[int, npt.NDArray[np.float64]]] = {}
    for m in rows:
        n, total = pooled.get(m.source, (0, np.zeros(3)))
        pooled[m.source] = (n + m.n_hold, total + m.n_hold * np.array(m.mse()))
    raw = pooled.get(ACCEL_MAG)
    raw_mse = raw[1] / raw[0] if raw else np.full(3, math.nan)
    mse_rows = []
    for source, (n, total) in pooled.items():
        mse = total / n
        with np.errstate(divide="ignore", invalid="ignore"):
            reduction = 100.0 * (1.0 - mse / raw_mse)
        mse_rows.append(MseRow(source, n, *(float(v) for v in mse), *(float(v) for v in reduction)))
    return ProtocolTables(protocol, tuple(chosen), tuple(rows), tuple(means), tuple(mse_rows))
