"""How a declared gain is drawn as a slider, on the page and in viser's panel.

Gains whose range is many times their default (process noises 0..100 with default 0.02) get a
log10 slider, the others a linear one. Changing a gain is the Station's command (`set_gain`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from gcs.core.gains import Gain

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
