"""The Python API for notebooks and scripts.

    import gcs
    s = gcs.open_session("sessions/2026-05-01_10-00-00_quad")   # or a .tlog, .bin, .ulg
    s.sources                        # ['ahrs2', 'onboard', 'truth', 'dcm', 'ekf', 'kf']
    dcm = s.attitude_df("dcm")       # pandas: t, wall_time, roll, pitch, yaw (rad)
    s.errors_df()                    # whole-run RMS / max error (deg) per estimator and reference

    t = gcs.estimate("flight.tlog", estimator="dcm", gains={"kp_rp": 0.3})  # pyarrow: t, roll, pitch, yaw

Tables are pyarrow Tables; every `*_df` method returns the same as a pandas DataFrame (pandas is
optional: it is imported only then, with a clear error when it is missing). Units are SI
(radians, s) except where a column name says deg; `t` is the vehicle clock (s since boot) and
`wall_time` the host's UNIX time (NaN where a log has none). A log file is run through every
estimator on open, as `gcs replay` and `gcs export` do.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import pyarrow as pa
import pyarrow.compute as pc

from gcs.sessions.contents import Contents, open_contents
from gcs.sessions.sources import open_source
from gcs.sessions.whatif import run_estimator

if TYPE_CHECKING:
    import pandas

__all__ = ["ESTIMATE_SCHEMA", "Session", "estimate", "open_session"]

#: What `estimate` returns: one row per IMU sample the estimator produced an attitude for.
ESTIMATE_SCHEMA = pa.schema(
    [("t", pa.float64()), ("roll", pa.float64()), ("pitch", pa.float64()), ("yaw", pa.float64())]
)


def _pandas() -> None:
    try:
        import pandas  # noqa: F401, PLC0415  (optional: only DataFrames need it)
    except ImportError as exc:
        raise ImportError("gcs: DataFrames need pandas, which is not installed (pip install pandas)") from exc


def to_pandas(table: pa.Table) -> pandas.DataFrame:
    """A pyarrow table as a pandas DataFrame; ImportError with the fix when pandas is missing."""
    _pandas()
    return table.to_pandas()


@dataclass(frozen=True)
class Session:
    """A recorded session or a log, opened by `open_session`. Tables are read (or computed) on
    first use and kept."""

    path: Path
    kind: str  # "session", "tlog", "dataflash", "ulog"
    _contents: Contents

    @property
    def sources(self) -> list[str]:
        """Every attitude source: references (onboard, ahrs2, truth) first, then estimators."""
        return self._contents.sources

    @property
    def estimators(self) -> list[str]:
        return self._contents.estimators()

    @property
    def references(self) -> list[str]:
        return self._contents.references()

    @property
    def attitude(self) -> pa.Table:
        """Every source's attitude: wall_time (UNIX s), t (vehicle s), source, roll, pitch, yaw (rad)."""
        return self._contents.attitude

    def source(self, name: str) -> pa.Table:
        """One source's attitude in time order (within each boot of the vehicle, the boots in the
        order recorded): t, boot (1 = the first; t starts again at each), wall_time, roll, pitch,
        yaw (rad). KeyError names the sources there are."""
        if name not in self.sources:
            raise KeyError(f"no source {name!r} in {self.path}; there are {', '.join(self.sources)}")
        data, boots = self._contents.boot_series(name)
        columns = {c: data[:, k] for k, c in enumerate(("t", "roll", "pitch", "yaw", "wall_time"))}
        return pa.table({**columns, "boot": boots + 1}).select(["t", "boot", "wall_time", "roll", "pitch", "yaw"])

    @property
    def comparison(self) -> pa.Table:
        """The live comparison snapshots recorded (estimator, reference, n, RMS / max error deg,
        lag); empty, with the same columns, for a log file."""
        return self._contents.comparison

    def errors(self) -> pa.Table:
        """Whole-run RMS and max |error| (deg) of every estimator against every reference."""
        return self._contents.errors()

    @property
    def events(self) -> pa.Table:
        """The session's events (gain changes, parameter writes, notes, link changes): wall_time,
        kind, client, estimator, gain, old, new, text, and the whole event as JSON in `data`."""
        return self._contents.events

    @property
    def imu(self) -> pa.Table:
        """Raw IMU samples fed to the estimators: t, source, gyro_* (rad/s), accel_* (m/s²), mag_* (gauss)."""
        return self._contents.imu

    def gain_changes(self) -> pa.Table:
        events = self.events
        return events.filter(pc.equal(events["kind"], "gain"))

    def attitude_df(self, source: str | None = None) -> pandas.DataFrame:
        """`source(name)` (or every source's `attitude`) as a DataFrame."""
        return to_pandas(self.attitude if source is None else self.source(source))

    def comparison_df(self) -> pandas.DataFrame:
        return to_pandas(self.comparison)

    def errors_df(self) -> pandas.DataFrame:
        return to_pandas(self.errors())

    def events_df(self) -> pandas.DataFrame:
        return to_pandas(self.events)

    def imu_df(self) -> pandas.DataFrame:
        return to_pandas(self.imu)


def open_session(path: str | os.PathLike) -> Session:
    """Open a session folder, .tlog, .bin or .ulg (a log is decoded and run through every
    estimator). gcs.logs.logfile.InputError names what is wrong with bad input, and where."""
    contents = open_contents(path)
    return Session(Path(path), contents.kind, contents)


def estimate(log: str | os.PathLike, estimator: str = "dcm", gains: dict[str, float] | None = None) -> pa.Table:
    """Run one estimator over a session or log with its recorded preset and gains, `gains`
    held fixed on top (recorded changes to other gains still apply where they happened). Returns
    t (vehicle s), roll, pitch, yaw (rad) per IMU sample. KeyError: unknown estimator;
    GainError: bad gain name or value; InputError: bad input."""
    source = open_source(log)
    run = run_estimator(source, estimator, dict(gains or {}))
    return pa.table(
        [run.t, run.euler[:, 0], run.euler[:, 1], run.euler[:, 2]],
        schema=ESTIMATE_SCHEMA,
    )
