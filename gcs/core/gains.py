"""Declared tunables: every estimator gain is declared once, here-shaped, and everything else
(sliders, REST validation, recorded change events, `gcs estimate --list`, docs) reads the
declaration instead of repeating its bounds.
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass


class GainError(ValueError):
    """A gain name or value that the declaration does not allow."""


@dataclass(frozen=True, slots=True)
class Gain:
    """One tunable: name, default, inclusive bounds, unit and one line of meaning."""

    name: str
    default: float
    min: float
    max: float
    unit: str
    meaning: str

    def __post_init__(self) -> None:
        if not (self.min <= self.default <= self.max):
            raise GainError(f"gain {self.name}: default {self.default} outside [{self.min}, {self.max}]")

    def validate(self, value: float) -> float:
        """The value as a float, or GainError naming the gain, the value and the bounds."""
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise GainError(f"gain {self.name}: {value!r} is not a number") from None
        if not math.isfinite(v):
            raise GainError(f"gain {self.name}: {value!r} is not finite")
        if not (self.min <= v <= self.max):
            raise GainError(f"gain {self.name}: {v:g} {self.unit} is outside [{self.min:g}, {self.max:g}] {self.unit}")
        return v


class GainSet:
    """The current values of a set of declared gains, changed only through validation."""

    def __init__(self, declarations: Iterable[Gain], presets: Mapping[str, Mapping[str, float]] | None = None):
        self.declarations: dict[str, Gain] = {g.name: g for g in declarations}
        self.presets: dict[str, dict[str, float]] = {k: dict(v) for k, v in (presets or {}).items()}
        self.values: dict[str, float] = {name: g.default for name, g in self.declarations.items()}
        self.version = 0  # counts changes: compiled estimators re-read the values when it moves
        for preset, values in self.presets.items():
            for name, value in values.items():
                self._declaration(name, context=f"preset {preset}").validate(value)

    def _declaration(self, name: str, context: str = "") -> Gain:
        try:
            return self.declarations[name]
        except KeyError:
            where = f" ({context})" if context else ""
            known = ", ".join(self.declarations)
            raise GainError(f"unknown gain {name!r}{where}; known: {known}") from None

    def __getitem__(self, name: str) -> float:
        return self.values[name]

    def set(self, name: str, value: float) -> tuple[float, float]:
        """Validate and apply one value; returns (old, new)."""
        new = self._declaration(name).validate(value)
        old = self.values[name]
        self.values[name] = new
        self.version += 1
        return old, new

    def apply_preset(self, preset: str) -> None:
        """Reset every gain to its default, then apply the preset's values."""
        if preset not in self.presets:
            raise GainError(f"unknown preset {preset!r}; known: {', '.join(self.presets)}")
        self.values = {name: g.default for name, g in self.declarations.items()}
        self.values.update(self.presets[preset])
        self.version += 1


@dataclass(frozen=True)
class PresetFile:
    """A tuning preset kept in a TOML file (`gcs sweep` writes one, `gcs estimate --preset-file`
    and `gcs replay --preset-file` load it): an estimator's built-in preset and gains over it.

        estimator = "dcm"
        preset = "ardupilot"
        note = "gcs sweep over 12 flights, rms_vs_truth 0.41 deg"
        [gains]
        kp_rp = 0.37
    """

    estimator: str
    preset: str | None
    gains: dict[str, float]
    note: str = ""

    def to_toml(self) -> str:
        lines = [f"estimator = {json.dumps(self.estimator)}"]
        if self.preset is not None:
            lines.append(f"preset = {json.dumps(self.preset)}")
        if self.note:
            lines.append(f"note = {json.dumps(self.note)}")
        lines.append("\n[gains]")
        lines += [f"{name} = {float(value)!r}" for name, value in self.gains.items()]
        return "\n".join(lines) + "\n"

    @classmethod
    def from_toml(cls, text: str, origin: str = "preset file") -> PresetFile:
        """Parse a preset file; GainError names the file and what is wrong (values are checked
        against the declarations when the estimator is created)."""
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise GainError(f"{origin}: not TOML ({exc})") from None
        estimator, preset, gains = data.get("estimator"), data.get("preset"), data.get("gains", {})
        if not isinstance(estimator, str):
            raise GainError(f'{origin}: no estimator = "NAME"')
        if preset is not None and not isinstance(preset, str):
            raise GainError(f"{origin}: preset must be a string")
        if not isinstance(gains, dict) or not all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in gains.values()
        ):
            raise GainError(f"{origin}: [gains] must hold NAME = number lines")
        return cls(estimator, preset, {k: float(v) for k, v in gains.items()}, str(data.get("note", "")))
