"""Declared tunables: every estimator gain is declared once, here-shaped, and everything else
(sliders, REST validation, recorded change events, `gcs estimate --list`, docs) reads the
declaration instead of repeating its bounds.
"""

from __future__ import annotations

import math
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
        return old, new

    def apply_preset(self, preset: str) -> None:
        """Reset every gain to its default, then apply the preset's values."""
        if preset not in self.presets:
            raise GainError(f"unknown preset {preset!r}; known: {', '.join(self.presets)}")
        self.values = {name: g.default for name, g in self.declarations.items()}
        self.values.update(self.presets[preset])
