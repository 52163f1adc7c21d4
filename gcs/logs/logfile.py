"""What every log reader reports besides its samples, and how it fails (`InputError`)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator

from gcs.core.samples import AttitudeSample, GpsSample, ImuSample


class InputError(ValueError):
    """Unreadable input; the message says which file, where, which field and what value."""


class LogFile:
    """Base of the log readers: iterate it for samples; afterwards `counts` per record type or
    topic used, `first_us` / `last_us` (the time span of those records, µs), `damage` (None,
    or where and why reading stopped early or skipped data) and `notes` (sensors the log lacks,
    so a gyro-only heading is explained rather than hidden). `imu` selects the IMU instance
    (0: the first, the one the autopilot uses by default)."""

    def __init__(self, path: str, imu: int = 0) -> None:
        self.path = path
        self.imu = imu
        self.counts: Counter[str] = Counter()
        self.first_us: int | None = None
        self.last_us: int | None = None
        self.damage: str | None = None
        self.notes: list[str] = []

    def __iter__(self) -> Iterator[ImuSample | GpsSample | AttitudeSample]:
        raise NotImplementedError  # each reader yields its samples in time order

    def _seen(self, kind: str, timestamp_us: int) -> None:
        """Count one record of `kind` read at timestamp_us (records come in time order)."""
        self.counts[kind] += 1
        if self.first_us is None:
            self.first_us = timestamp_us
        self.last_us = timestamp_us
