"""Peak memory of `gcs replay --fast` on a one-hour 400 Hz log.

The log is made by the simulator (PX4 profile, quad script: HIGHRES_IMU at 400 Hz, ATTITUDE at
50 Hz, GPS, SIMSTATE ...), one hour of vehicle time written as fast as the CPU allows (about 20
minutes here), and kept in `~/.cache/gcs-bench/` for later runs. Each replay runs in a process of
its own that reports its peak RSS (`ru_maxrss`). Baseline: the same replay of the log's first
minute, i.e. what the process costs before the flight's length counts. Before the columnar
source (docs/benchmarks.md), the hour took 1,595 MiB.

    python -m bench.replay_memory [--minutes 60] [--estimator dcm]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
from pathlib import Path

from gcs.mavlink.dialect import Encoder, mavlink
from gcs.mavlink.tlog import tlog_record
from gcs.sim import SimVehicle

CACHE = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "gcs-bench"
IMU_HZ = 400
BASE_US = 1_700_000_000_000_000


def simulated_log(path: Path, seconds: float) -> None:
    """A tlog of the simulated PX4 quad with HIGHRES_IMU at IMU_HZ (written to a temporary name first)."""
    sim = SimVehicle(profile="px4", script="quad", seed=1)
    encoder = Encoder(255, 190)
    for msg_id, hz in ((mavlink.MAVLINK_MSG_ID_HIGHRES_IMU, IMU_HZ), (mavlink.MAVLINK_MSG_ID_ATTITUDE, 50)):
        command = mavlink.MAVLink_command_long_message(
            1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id, 1e6 / hz, 0, 0, 0, 0, 0
        )
        sim.handle_bytes(encoder.encode(command))
    partial = path.with_suffix(".partial")
    with open(partial, "wb") as fh:
        for k in range(1, int(seconds * IMU_HZ) + 1):
            t = k / IMU_HZ
            fh.write(b"".join(tlog_record(BASE_US + int(t * 1e6) & ~3, p) for p in sim.advance(t)))
    partial.rename(path)


def log_of(minutes: float) -> Path:
    path = CACHE / f"px4-quad-{IMU_HZ}hz-{minutes:g}min.tlog"
    if not path.exists():
        CACHE.mkdir(parents=True, exist_ok=True)
        print(f"simulating {minutes:g} min of flight into {path} ...", file=sys.stderr, flush=True)
        simulated_log(path, minutes * 60)
    return path


def peak_rss(path: Path, estimator: str) -> dict:
    """Replay path in a child process; its peak RSS (MiB), IMU samples and the source's array bytes."""
    child = subprocess.run(
        [sys.executable, "-m", "bench.replay_memory", "--child", str(path), "--estimator", estimator],
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(child.stdout.strip().splitlines()[-1])


def child(path: str, estimator: str) -> None:
    from gcs.runtime.replay import ReplaySession
    from gcs.sessions.sources import open_source

    source = open_source(path)
    session = ReplaySession(source, speed=0, estimators=[estimator])
    session.run_to_end()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    imu = source.table.imu_count
    print(json.dumps({"rss_mib": round(peak, 1), "imu": imu, "bytes_per_imu": round(source.nbytes / imu, 1)}))


def main(minutes: float = 60, estimator: str = "dcm") -> list[dict]:
    hour, minute = log_of(minutes), log_of(1)
    ours, base = peak_rss(hour, estimator), peak_rss(minute, estimator)
    return [
        {
            "benchmark": f"replay --fast -e {estimator}, {minutes:g} min @ {IMU_HZ} Hz",
            "baseline": "same replay of 1 min",
            "baseline_mib": base["rss_mib"],
            "ours_mib": ours["rss_mib"],
            "ratio": round(ours["rss_mib"] / base["rss_mib"], 2),
            "unit": "MiB peak RSS",
            "n": ours["imu"],
            "bytes_per_imu": ours["bytes_per_imu"],
            "log_mib": round(hour.stat().st_size / 2**20, 1),
        }
    ]


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--minutes", type=float, default=60)
    parser.add_argument("--estimator", default="dcm")
    parser.add_argument("--child")
    args = parser.parse_args()
    if args.child:
        child(args.child, args.estimator)
    else:
        for row in main(args.minutes, args.estimator):
            print(row)
