"""What every log reader reports besides its samples, and how it fails (`InputError`)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator

from gcs.core.declination import VehicleDeclination
from gcs.core.estimation import GainChange
from gcs.core.samples import AttitudeSample, GpsSample, ImuSample
from gcs.logs.input_table import InputTable, InputTableBuilder


class InputError(ValueError):
    """Unreadable input; the message says which file, where, which field and what value."""


def no_imu_samples(path: str) -> InputError:
    """Why a log whose IMU messages or records gave no sample makes no estimate: every command that
    estimates refuses it with this line."""
    return InputError(f"{path}: no IMU samples: nothing to estimate from")


class LogFile:
    """Base of the log readers: iterate it for samples; afterwards `counts` per record type or
    topic used, `first_us` / `last_us` (the time span of those records, µs), `damage` (None,
    or where and why reading stopped early or skipped data) and `notes` (sensors the log lacks,
    so a gyro-only heading is explained rather than hidden), `declination` (the declination its
    parameters or, failing them, the World Magnetic Model at its first 3D fix gave, and the
    source: yielded as `GainChange`s where it changes, as from a .tlog), `vehicle` (its label as
    gcs.mavlink.identity makes it from what the log says, None when it says nothing) and
    `firmware` (its version as the log gives it, None when it does not). `imu`
    selects the IMU instance (0: the first, the one the autopilot uses by default)."""

    def __init__(self, path: str, imu: int = 0) -> None:
        self.path = path
        self.imu = imu
        self.counts: Counter[str] = Counter()
        self.first_us: int | None = None
        self.last_us: int | None = None
        self.damage: str | None = None
        self.notes: list[str] = []
        self.declination = VehicleDeclination()
        self.vehicle: str | None = None
        self.firmware: str | None = None

    def __iter__(self) -> Iterator[ImuSample | GpsSample | AttitudeSample | GainChange]:
        raise NotImplementedError  # each reader yields its samples in time order

    def columns(self) -> InputTable:
        """The samples as an input table, and the same reports; a reader that decodes straight
        into columns gives them without the objects."""
        table = InputTableBuilder()
        for sample in self:
            table.append(sample)
        return table.build()

    def _seen(self, kind: str, timestamp_us: int) -> None:
        """Count one record of `kind` read at timestamp_us (records come in time order)."""
        self.counts[kind] += 1
        if self.first_us is None:
            self.first_us = timestamp_us
        self.last_us = timestamp_us
