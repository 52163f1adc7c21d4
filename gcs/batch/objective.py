"""What a sweep searches and minimises: gain ranges (`NAME=LOW:HIGH`) and the per-flight score.
Kept apart from the Dask driver so the command line can be built without importing Dask."""

from __future__ import annotations

import math
from dataclasses import dataclass

from gcs.core.estimators import registry
from gcs.core.gains import GainError

#: objective → the reference it scores against
OBJECTIVES = {"rms_vs_truth": "truth", "rms_vs_onboard": "onboard"}


@dataclass(frozen=True)
class GainRange:
    """One gain searched between low and high (inclusive)."""

    name: str
    low: float
    high: float


def parse_range(text: str, estimator: str) -> GainRange:
    """`NAME=LOW:HIGH` → GainRange, both ends inside the gain's declared bounds; GainError if not."""
    name, sep, span = text.partition("=")
    low_text, colon, high_text = span.partition(":")
    try:
        low, high = float(low_text), float(high_text)
    except ValueError:
        raise GainError(f"--gain {text!r}: expected NAME=LOW:HIGH with numbers") from None
    if not sep or not colon or not low < high:
        raise GainError(f"--gain {text!r}: expected NAME=LOW:HIGH with LOW < HIGH")
    declared = {g.name: g for g in registry.get(estimator).GAINS}
    if name not in declared:
        raise GainError(f"--gain {text!r}: {estimator} has no gain {name!r}; known: {', '.join(declared)}")
    declared[name].validate(low)
    declared[name].validate(high)
    return GainRange(name, low, high)


def score(errors: dict[str, dict[str, list[float]]], reference: str) -> float:
    """Total RMS error (deg) against reference; NaN when the flight does not have it."""
    if reference not in errors:
        return math.nan
    return math.sqrt(sum(v * v for v in errors[reference]["rms"]) / 3)
