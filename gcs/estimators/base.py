"""What every attitude estimator offers, so the live pipeline, `gcs estimate`, replay and the
dashboard treat them alike."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar

import numpy as np

from gcs.estimators.gains import Gain, GainSet
from gcs.sensors import GpsSample, ImuSample


class AttitudeEstimator(ABC):
    """An attitude filter fed SI samples in time order.

    Subclasses declare `name`, `GAINS` (the tunables) and `PRESETS`; the current values live in
    `self.gains` and may change between any two samples (`set_gain`) without a restart or a jump
    in the output.
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

    def set_gain(self, name: str, value: float) -> tuple[float, float]:
        """Validate and apply one gain now; returns (old, new)."""
        return self.gains.set(name, value)

    @abstractmethod
    def update_imu(self, sample: ImuSample) -> bool:
        """Advance to sample.t and fuse it. Returns True once the attitude is valid."""

    def update_gps(self, sample: GpsSample) -> None:
        """Fuse a GPS fix (velocity/course aiding). Estimators that ignore GPS keep this."""

    @property
    @abstractmethod
    def quaternion(self) -> np.ndarray:
        """Current attitude, unit quaternion (w, x, y, z), body FRD → earth NED."""

    @abstractmethod
    def health(self) -> dict[str, float]:
        """Numbers that tell whether to trust the output (accel norm, innovations, ...)."""
