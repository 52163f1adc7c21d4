"""The one rule by which a log's separate magnetometer readings reach the estimators.

A live RAW_IMU message carries the autopilot's latest compass reading with every IMU sample, and
the estimators read the field from `ImuSample.mag`. Logs record the magnetometer as its own
record or topic at its own rate, so the readers keep the latest reading and attach it to every
IMU sample that follows it: offline input then matches live input.
"""

from __future__ import annotations

import dataclasses

from gcs.core.samples import ImuSample, MagSample


def with_latest_mag(sample: ImuSample, mag: MagSample | None) -> ImuSample:
    """sample carrying the latest magnetometer reading (unchanged while none has been read)."""
    return sample if mag is None else dataclasses.replace(sample, mag=mag.field)
