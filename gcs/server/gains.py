"""Changing estimator gains from any UI (REST for the page and scripts, viser's panel), with one
code path: validate through the Gain declaration, apply to the running estimator, record a
"gain" event (old, new, client) in the station's event log. Both UIs follow the event log, so a
change made in one shows in the other.

Slider shape also comes from the declaration: gains whose range is many times their default
(process noises 0..100 with default 0.02) get a log10 slider, the others a linear one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from gcs.core.gains import Gain, GainSet
from gcs.runtime.station import GroundStation

#: Steps across a slider.
SLIDER_STEPS = 1000
#: A range this many times the default (or the smallest preset value) gets a log slider.
LOG_RATIO = 100.0


@dataclass(frozen=True, slots=True)
class SliderSpec:
    """How to draw a gain as a slider: position p in [lo, hi] by step; value = p (linear) or
    10**p (log; the value's min may be 0, which a log slider reaches only by typing it)."""

    scale: str  # "linear" or "log"
    lo: float
    hi: float
    step: float


def slider_spec(gain: Gain, presets: dict[str, dict[str, float]]) -> SliderSpec:
    typical = [v for v in (gain.default, *(p[gain.name] for p in presets.values() if gain.name in p)) if v > 0]
    if gain.min >= 0 and typical and gain.max / min(typical) >= LOG_RATIO:
        lo = math.log10(gain.min if gain.min > 0 else min(typical) / 1000)
        hi = math.log10(gain.max)
        return SliderSpec("log", lo, hi, (hi - lo) / SLIDER_STEPS)
    return SliderSpec("linear", gain.min, gain.max, (gain.max - gain.min) / SLIDER_STEPS)


class GainControl:
    """Set one gain or reset an estimator to a preset, recording every change."""

    def __init__(self, station: GroundStation) -> None:
        if station.estimation is None:
            raise ValueError("the station runs without estimation: no gains to tune")
        self.station = station
        self.pipeline = station.estimation.pipeline

    def estimator(self, name: str):
        """The running estimator; KeyError names the running ones."""
        if name not in self.pipeline.estimators:
            raise KeyError(f"unknown estimator {name!r}; running: {', '.join(self.pipeline.estimators)}")
        return self.pipeline.estimators[name]

    def set(self, estimator: str, gain: str, value: float, client: str) -> tuple[float, float]:
        """Apply one value now; GainError (bad value or name) / KeyError (estimator)."""
        old, new = self.pipeline.set_gain(estimator, gain, value)
        if new != old:
            self.station.events.record("gain", client, estimator=estimator, gain=gain, old=old, new=new)
        return old, new

    def reset(self, estimator: str, preset: str | None, client: str) -> dict[str, tuple[float, float]]:
        """Set every gain to the preset's value (default preset: the estimator's own), except a
        declination the vehicle reported. Returns the changes {gain: (old, new)}."""
        est = self.estimator(estimator)
        preset = preset or est.DEFAULT_PRESET
        target = GainSet(est.gains.declarations.values(), est.gains.presets)
        target.apply_preset(preset)  # GainError names the known presets
        changes = {}
        for name, value in target.values.items():
            if name == "declination" and self.pipeline.declination is not None:
                continue
            old, new = self.set(estimator, name, value, client)
            if new != old:
                changes[name] = (old, new)
        est.preset = preset
        return changes
