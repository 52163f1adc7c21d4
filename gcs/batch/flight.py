"""One flight through the estimators into its dataset partition: the task `gcs batch` runs.

The flight is decoded by `open_source` and fed to `ReplaySource.new_pipeline` exactly as
`gcs replay --fast` feeds it, so the comparison figures are the replay's, bit for bit. The
attitude points are kept only until the partition is written; the task returns a `FlightResult`
of a few numbers, so the driver never holds a flight's data.
"""

from __future__ import annotations

import math
import os
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa

from gcs.batch import dataset
from gcs.core.estimation import AttitudePoint, EstimationPipeline
from gcs.logs.logfile import InputError
from gcs.sessions import columnar, layout
from gcs.sessions.contents import boot_numbers, events_table, read_events
from gcs.sessions.sources import ReplaySource, open_source


@dataclass(frozen=True)
class FlightResult:
    """What a batch task sends back: where the flight went and its headline errors."""

    flight: str
    path: str
    ok: bool
    reason: str = ""  # why it failed
    duration_s: float = 0.0
    imu_samples: int = 0
    #: (estimator, reference) → RMS roll, pitch, yaw (deg)
    rms: dict[tuple[str, str], tuple[float, float, float]] = field(default_factory=dict)


@dataclass(frozen=True)
class FlightFacts:
    """What a flight is, beside its numbers."""

    vehicle: str
    firmware: str
    started: float
    imu_rate_hz: float


def facts(source: ReplaySource) -> FlightFacts:
    """Vehicle and firmware from a session's meta.json ("unknown" for a bare log), start time (the
    session's, else the file's mtime) and the mean IMU rate (`imu_rate`)."""
    recorded = source.meta.get("vehicle")
    vehicle: dict = recorded if isinstance(recorded, dict) else {}
    started = layout.meta_time(source.meta.get("start"))
    if started is None:
        started = os.stat(source.packet_file or source.path).st_mtime
    return FlightFacts(
        str(vehicle.get("label") or "unknown"), str(vehicle.get("firmware") or ""), started, imu_rate(source)
    )


def imu_rate(source: ReplaySource) -> float:
    """IMU samples per second of IMU time, each boot of the vehicle over its own span: across a
    reboot (its clock from 0 again) the first sample to the last spanned the last boot alone, and
    a session of two boots read about twice its rate."""
    t = source.table.imu[:, 0]
    boots = np.split(t, np.flatnonzero(np.diff(boot_numbers(t))) + 1) if len(t) else []
    span = sum(float(b[-1] - b[0]) for b in boots)
    return (len(t) - len(boots)) / span if span > 0 else 0.0


def comparison_table(pipeline: EstimationPipeline) -> pa.Table:
    """Whole-flight RMS / max / lag per estimator and reference (columnar.COMPARISON_SCHEMA, no
    wall time): the figures `gcs replay` prints, unrounded."""
    rows = []
    for name, comparison in pipeline.comparisons.items():
        summary = comparison.summary()
        for ref, stats in summary["references"].items():
            s = stats["session"]
            rows.append(
                {
                    "wall_time": math.nan,
                    "estimator": name,
                    "reference": ref,
                    "n": s["n"],
                    **{f"rms_{a}": v for a, v in zip(("roll", "pitch", "yaw"), s["rms"])},
                    **{f"max_{a}": v for a, v in zip(("roll", "pitch", "yaw"), s["max"])},
                    "lag_s": summary["lag"],
                    "imu_rate_hz": summary["imu_rate"],
                }
            )
    return pa.Table.from_pylist(rows, schema=columnar.COMPARISON_SCHEMA)


def summary_table(
    source: ReplaySource, pipeline: EstimationPipeline, comparison: pa.Table, about: FlightFacts
) -> pa.Table:
    reliable = {name: c.reliability()[0] for name, c in pipeline.comparisons.items()}
    flight = {
        "path": layout.utf8_text(source.path),
        "kind": source.kind,
        "vehicle": about.vehicle,
        "firmware": about.firmware,
        "started": about.started,
        "duration_s": source.duration,
        "imu_samples": pipeline.imu_samples,
        "imu_rate_hz": about.imu_rate_hz,
        "damage": None if source.damage is None else layout.utf8_text(source.damage),
    }
    keep = [c for c in comparison.column_names if c not in ("wall_time", "imu_rate_hz")]  # the flight's rate instead
    rows = [{**flight, **row, "reliable": reliable[row["estimator"]]} for row in comparison.select(keep).to_pylist()]
    return pa.Table.from_pylist(rows, schema=dataset.SUMMARY_SCHEMA)


def attitude_table(points: list[AttitudePoint]) -> pa.Table:
    """Every attitude the replay produced (references and estimators), no wall time."""
    schema = columnar.ATTITUDE_SCHEMA
    return pa.table(
        {
            "wall_time": np.full(len(points), math.nan),
            "t": np.fromiter((p.t for p in points), np.float64, len(points)),
            "source": pa.array([p.source for p in points], pa.string()),
            "roll": np.fromiter((p.roll for p in points), np.float64, len(points)),
            "pitch": np.fromiter((p.pitch for p in points), np.float64, len(points)),
            "yaw": np.fromiter((p.yaw for p in points), np.float64, len(points)),
        },
        schema=schema,
    )


def replay_flight(
    source: ReplaySource, estimators: list[str] | None, gains: dict[str, dict[str, float]]
) -> tuple[EstimationPipeline, list[AttitudePoint]]:
    """The source through a pipeline as `gcs replay --fast` runs it; every point it produced."""
    points: list[AttitudePoint] = []
    pipeline = source.replay(source.new_pipeline(estimators, gains), points.extend)
    return pipeline, points


def process_flight(
    path: str,
    out: str,
    estimators: list[str] | None = None,
    gains: dict[str, dict[str, float]] | None = None,
) -> FlightResult:
    """Read, replay and write one flight into the dataset at `out`. A log that cannot be read (or
    any error while processing it) becomes its failure row, never an exception of the task."""
    flight = dataset.flight_id(path)
    root = Path(out)
    try:
        source = open_source(path)
        source.require_imu()  # a failure row, as `gcs replay` and `gcs estimate` refuse it
        pipeline, points = replay_flight(source, estimators, gains or {})
        comparison = comparison_table(pipeline)
        events = events_table(read_events(Path(path))) if source.kind == "session" else events_table([])
        tables = {
            "attitude": attitude_table(points),
            "comparison": comparison,
            "events": events,
            "summary": summary_table(source, pipeline, comparison, facts(source)),
        }
        del points
        dataset.write_flight(root, flight, tables)
    except InputError as exc:
        dataset.write_failure(root, flight, layout.utf8_text(path), layout.utf8_text(str(exc)))
        return FlightResult(flight, path, False, str(exc))
    except Exception as exc:  # one broken flight must not stop the fleet: record it with where it broke
        where = traceback.extract_tb(exc.__traceback__)[-1]
        reason = f"{path}: {type(exc).__name__}: {exc} ({os.path.basename(where.filename)}:{where.lineno})"
        dataset.write_failure(root, flight, layout.utf8_text(path), layout.utf8_text(reason))
        return FlightResult(flight, path, False, reason)
    rms = {
        (row["estimator"], row["reference"]): (row["rms_roll"], row["rms_pitch"], row["rms_yaw"])
        for row in comparison.to_pylist()
    }
    return FlightResult(flight, path, True, "", source.duration, pipeline.imu_samples, rms)
