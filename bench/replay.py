"""Replay throughput and what-if re-run time.

Row 1, replay of `arducopter-sitl-hop.BIN` (real DataFlash, IMU logged at 25 Hz per instance
over 98 s, 177,000 records of 190 types): ours = decode (the column reader, gcs.logs.dataflash)
+ the `dcm` and `ekf` estimators + the session table, as `gcs replay --fast` runs it (whole
runs). Baseline `pymavlink`: a bare DFReader pass over the same file (`recv_msg` until None: the
loop mavlogdump runs), which decodes every record and estimates nothing. Both as IMU samples/s;
ratio > 1: we are faster. Beside it, before/after in the same run: the decoding's CPU (the file
to the input table) and the whole replay's × real time with the record-by-record reader on
DFReader that the column reader replaced (tests/dataflash_reference.py), and the figure
`gcs replay --fast` prints (its own process).

Rows 2-4, what-if on a 10-minute session at 50 Hz made with the simulator's `advance()`
(RAW_IMU, ATTITUDE, AHRS2, SIMSTATE ... at 50 Hz): the time `what_if` takes to re-run one
estimator with a changed gain once the source is decoded (cached). Baseline: re-decoding the
tlog and replaying it through every estimator, which is what a tool without the cache does;
beside it the CPU of the same what-if with the readable reference estimator.

Row 5, replay of the PX4 .ulg end to end (decode + the three estimators + the session table, as
`gcs replay --fast` runs it: whole runs) in × real time, against a bare pyulog parse of the file
(ratio > 1: the whole replay takes less than pyulog's parse alone; the decoding's own CPU beside it);
beside it the per-sample pipeline, and the figure `gcs replay --fast` prints (its own process).
"""

from __future__ import annotations

import contextlib
import os
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

from pyulog import ULog

from gcs.core.estimators import registry
from gcs.runtime.replay import ReplaySession, whole_table
from gcs.sessions import sources
from gcs.sessions.sources import ReplaySource, open_source
from gcs.sessions.whatif import run_estimator, what_if
from gcs.sessions.workbench import Workbench
from gcs.sim.recording import write_tlog

LOGS = Path(__file__).resolve().parents[2] / "shared" / "data" / "logs"
BIN = LOGS / "arducopter-sitl-hop.BIN"
ULOG = LOGS / "px4-flight-sample.ulg"
READABLE = {
    "dcm": "gcs.core.estimators.dcm:DcmEstimator",
    "kf": "gcs.core.estimators.kf:KalmanAttitudeFilter",
    "ekf": "gcs.core.estimators.ekf:EkfEstimator",
}
SESSION_S = 600.0
RATE_HZ = 50


def bare_dfreader(path: Path) -> float:
    from pymavlink import mavutil

    started = time.perf_counter()
    log = mavutil.mavlink_connection(str(path))
    while log.recv_msg() is not None:
        pass
    return time.perf_counter() - started


def replay(path: Path, estimators: list[str] | None) -> tuple[float, int, float]:
    """(seconds, IMU samples, log duration s) to decode and replay through the estimators to the
    session table, as `gcs replay --fast` does (whole runs)."""
    started = time.perf_counter()
    source = open_source(path)
    _, imu = whole_table(source, estimators or registry.names(), {})
    return time.perf_counter() - started, imu, source.duration


def decode_cpu(path: Path) -> float:
    """CPU s of decoding alone (open_source: the file to the input table), the rest of a replay
    being the estimators and the table."""
    cpu = time.process_time()
    open_source(path)
    return time.process_time() - cpu


@contextlib.contextmanager
def dfreader_decoding() -> Iterator[None]:
    """open_source reads .bin files with the record-by-record reader on DFReader meanwhile (the
    reader before the column reader, kept as the tests' reference)."""
    from tests.dataflash_reference import DfreaderLog

    column_reader = sources.LOG_FILES[".bin"]
    sources.LOG_FILES[".bin"] = DfreaderLog
    try:
        yield
    finally:
        sources.LOG_FILES[".bin"] = column_reader


def bin_replay_row() -> dict:
    """Row 1: the .BIN replay with the column reader against a bare DFReader pass, and the same
    replay and decoding with the DFReader reader before it, interleaved, best of three each."""
    replay(BIN, ["dcm", "ekf"])  # the kernels loaded
    base = min(bare_dfreader(BIN) for _ in range(2))
    runs: dict[str, list[tuple[float, float, float, int, float]]] = {"after": [], "before": []}
    for _ in range(3):
        for name in runs:
            with dfreader_decoding() if name == "before" else contextlib.nullcontext():
                cpu = time.process_time()
                wall, samples, duration = replay(BIN, ["dcm", "ekf"])
                cpu = time.process_time() - cpu
                runs[name].append((wall, cpu, decode_cpu(BIN), samples, duration))
    after, before = (min(runs[name]) for name in ("after", "before"))
    decode_after, decode_before = (min(r[2] for r in runs[name]) for name in ("after", "before"))
    samples, duration = after[3], after[4]
    assert before[3] == samples
    return {
        "benchmark": "replay .BIN decode+dcm+ekf",
        "baseline": "bare pymavlink DFReader pass",
        "baseline_per_s": round(samples / base),
        "ours_per_s": round(samples / after[0]),
        "ratio": round(base / after[0], 2),
        "unit": "IMU samples/s",
        "n": samples,
        "x_real_time": round(duration / after[0], 1),
        "x_real_time_cpu": round(duration / after[1], 1),
        "x_real_time_before": round(duration / before[0], 1),
        "x_real_time_cpu_before": round(duration / before[1], 1),
        "decode_cpu_s": round(decode_after, 4),
        "decode_cpu_s_before": round(decode_before, 4),
        "decode_ratio": round(decode_before / decode_after, 1),
        **printed_row(BIN),
        "load_avg_1m": round(os.getloadavg()[0], 2),
    }


def replay_per_sample(path: Path, estimators: list[str] | None) -> tuple[float, int, float]:
    """The same through the per-sample pipeline (what the live station and a paced replay run)."""
    started = time.perf_counter()
    source = open_source(path)
    session = ReplaySession(source, speed=0, estimators=estimators)
    session.run_to_end()
    return time.perf_counter() - started, session.pipeline.imu_samples, source.duration


def printed_x_real_time(path: Path) -> tuple[float, float]:
    """The "× real time" `gcs replay --fast` prints (a process of its own): the replay's own, file
    to table, and the one that counts the process's start-up too (numba's set-up, kernels loaded)."""
    out = subprocess.run(
        [sys.executable, "-m", "gcs", "replay", str(path), "--fast"], capture_output=True, text=True, check=True
    ).stdout
    own = re.search(r"\(([0-9.]+)x real time", out)
    with_start_up = re.search(r"([0-9.]+)x real time with it", out)
    return float(own.group(1)), float(with_start_up.group(1))  # type: ignore[union-attr]


def printed_row(path: Path) -> dict[str, float]:
    own, with_start_up = printed_x_real_time(path)
    return {
        "x_real_time_printed_by_gcs_replay_fast": own,
        "x_real_time_printed_with_start_up": with_start_up,
    }


def simulated_session(path: Path, seconds: float = SESSION_S) -> None:
    """A tlog of the simulated quad with every stream at RATE_HZ, written as fast as the CPU allows."""
    write_tlog(path, seconds, profile="pixhawk", script="quad", seed=1, rate_hz=RATE_HZ)


def main() -> list[dict]:
    rows = [bin_replay_row()]
    with tempfile.TemporaryDirectory() as tmp:
        tlog = Path(tmp) / "ten-minutes.tlog"
        simulated_session(tlog)
        full, imu, _ = replay_per_sample(tlog, None)
        bench = Workbench()
        source = bench.source(tlog)
        for estimator, gains in (("dcm", {"kp_rp": 0.4}), ("kf", {"r_roll": 0.04}), ("ekf", {"gyro_noise": 0.02})):
            what_if(source, estimator, {}, bench.run)  # the original run, cached as the dashboard's first view does
            cpu = time.process_time()
            result = what_if(source, estimator, gains, bench.run)
            cpu = time.process_time() - cpu
            readable = readable_what_if(source, estimator, gains)
            rows.append(
                {
                    "benchmark": f"what-if {estimator} 10 min @ {RATE_HZ} Hz",
                    "baseline": "re-decode + replay all estimators",
                    "baseline_s": round(full, 2),
                    "ours_s": round(result.elapsed_s, 3),
                    "ours_cpu_s": round(cpu, 3),
                    "reference_cpu_s": round(readable, 3),
                    "ratio": round(full / result.elapsed_s, 1),
                    "unit": "s",
                    "target": "≤ 0.2 s",
                    "n": imu,
                }
            )
    replay(ULOG, None)  # the whole-run kernels loaded
    cpu = time.process_time()
    ours, samples, duration = replay(ULOG, None)
    cpu = time.process_time() - cpu
    decode = min(decode_cpu(ULOG) for _ in range(3))
    per_sample, _, _ = replay_per_sample(ULOG, None)
    printed = printed_row(ULOG)
    base = time.perf_counter()
    ULog(str(ULOG))
    base = time.perf_counter() - base
    rows.append(
        {
            "benchmark": "replay PX4 .ulg end to end (decode + dcm + kf + ekf + comparisons)",
            "baseline": "bare pyulog parse of the file",
            "baseline_s": round(base, 3),
            "ours_s": round(ours, 3),
            "ratio": round(base / ours, 2),
            "ours_cpu_s": round(cpu, 3),
            "decode_cpu_s": round(decode, 3),
            "x_real_time": round(duration / ours, 1),
            "x_real_time_cpu": round(duration / cpu, 1),
            "x_real_time_per_sample_pipeline": round(duration / per_sample, 1),
            **printed,
            "target": "≥ 1000× real time",
            "n": samples,
            "load_avg_1m": round(os.getloadavg()[0], 2),
        }
    )
    return rows


def readable_what_if(source: ReplaySource, estimator: str, gains: dict[str, float]) -> float:
    """CPU s of the same what-if run with the readable reference class instead of the compiled one."""
    compiled = registry.ESTIMATORS[estimator]
    registry.ESTIMATORS[estimator] = READABLE[estimator]
    try:
        cpu = time.process_time()
        run_estimator(source, estimator, dict(gains))  # what_if's new run
        return time.process_time() - cpu
    finally:
        registry.ESTIMATORS[estimator] = compiled


if __name__ == "__main__":
    for row in main():
        print(row)
