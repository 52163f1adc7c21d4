"""Every log format → one time-ordered stream of samples (`ImuSample`, `GpsSample`,
`AttitudeSample`) on the vehicle clock, plus, from a .tlog, the declination `GainChange` the
live pipeline would make: `read_samples(path, imu)` picks the reader by suffix; `imu` is the
IMU instance to use (0: the first).
Bad input raises `InputError` naming the file, the line or byte offset, the field and the value.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable

from gcs.core.estimation import GainChange
from gcs.core.samples import AttitudeSample, GpsSample, ImuSample
from gcs.logs.csvfile import read_csv
from gcs.logs.dataflash import DataflashLog, DataflashTextLog
from gcs.logs.logfile import InputError
from gcs.logs.tlog import read_tlog
from gcs.logs.ulog import UlogFile

__all__ = ["READERS", "InputError", "Sample", "read_samples"]

Sample = ImuSample | GpsSample | AttitudeSample | GainChange

READERS: dict[str, Callable[[str, int], Iterable[Sample]]] = {
    ".csv": read_csv,
    ".tlog": read_tlog,
    ".bin": DataflashLog,
    ".log": DataflashTextLog,
    ".ulg": UlogFile,
}


def read_samples(path: str, imu: int = 0) -> Iterable[Sample]:
    """The sample stream of a log file, by suffix, with IMU instance `imu`; InputError for a
    missing file or unknown format. A `LogFile` reader reports damage and notes afterwards."""
    if os.path.isdir(path):  # a session folder, say: "no such file" sent the engineer looking for it
        raise InputError(f"{path}: a folder, not a log file; give a {', '.join(READERS)} file")
    if not os.path.isfile(path):
        raise InputError(f"{path}: no such file")
    suffix = os.path.splitext(path)[1].lower()
    reader = READERS.get(suffix)
    if reader is None:
        raise InputError(f"{path}: unknown input format {suffix!r}; known: {', '.join(READERS)}")
    return reader(path, imu)
