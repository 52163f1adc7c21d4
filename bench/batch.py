"""Fleet throughput of `gcs batch`: flights/s with 1, 2 and 4 local Dask workers.

16 simulated flights (pixhawk quad, every stream at 50 Hz, 10 minutes each by default; 4
distinct seeds, each copied 4 times: a task's work does not depend on the bytes being unique)
are made with gcs.sim.recording and kept in `~/.cache/gcs-bench/`. Baseline: the
single-process `gcs replay --fast` loop over the same flights in the same run (decode +
`ReplaySession.run_to_end` through the same estimators, one flight after another). Ours: the
time of `run_batch` on a LocalCluster of N worker processes (cluster start excluded, reported
apart), which also writes the Parquet dataset. Ratio > 1: the batch is faster than the loop.
Peak RSS per worker (`ru_maxrss` of each worker process after the run): what bounded memory
means per task.

    python -m bench.batch [--minutes 10] [--flights 16] [--workers 1 2 4] [-e dcm] [--quick]
"""

from __future__ import annotations

import argparse
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

from gcs.batch.cluster import connect
from gcs.batch.run import run_batch
from gcs.runtime.replay import ReplaySession
from gcs.sessions.sources import open_source
from gcs.sim.recording import write_tlog

CACHE = Path.home() / ".cache" / "gcs-bench"
SEEDS = 4


def flights(minutes: float, count: int) -> list[str]:
    """`count` flights of `minutes` (SEEDS distinct ones, cached) as files in a cache folder."""
    CACHE.mkdir(parents=True, exist_ok=True)
    distinct = []
    for seed in range(1, SEEDS + 1):
        path = CACHE / f"pixhawk-quad-50hz-{minutes:g}min-seed{seed}.tlog"
        if not path.exists():
            print(f"simulating {minutes:g} min into {path} ...", file=sys.stderr, flush=True)
            write_tlog(path, minutes * 60, seed=seed)
        distinct.append(path)
    folder = CACHE / f"fleet-{minutes:g}min-{count}"
    folder.mkdir(exist_ok=True)
    out = []
    for k in range(count):
        copy = folder / f"flight-{k:02d}.tlog"
        if not copy.exists():
            shutil.copyfile(distinct[k % SEEDS], copy)
        out.append(str(copy))
    return out


def replay_loop(paths: list[str], estimators: list[str] | None) -> float:
    started = time.perf_counter()
    for path in paths:
        ReplaySession(open_source(path), 0, estimators).run_to_end()
    return time.perf_counter() - started


def _peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def batch(paths: list[str], estimators: list[str] | None, workers: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        started = time.perf_counter()
        with connect(None, workers) as client:
            ready = time.perf_counter()
            outcome = run_batch(client, paths, Path(tmp) / "ds", estimators)
            elapsed = time.perf_counter() - ready
            rss = client.run(_peak_rss_mib)
    assert all(r.ok for r in outcome.done), [r.reason for r in outcome.done if not r.ok]
    return {"s": elapsed, "start_s": ready - started, "rss": max(rss.values())}


def main(minutes: float = 10, count: int = 16, workers: tuple[int, ...] = (1, 2, 4), estimators=None) -> list[dict]:
    paths = flights(minutes, count)
    base = replay_loop(paths, estimators)
    rows = []
    for n in workers:
        r = batch(paths, estimators, n)
        rows.append(
            {
                "benchmark": f"gcs batch, {n} local worker{'s' if n > 1 else ''}, {count} x {minutes:g} min @ 50 Hz"
                + (f" -e {','.join(estimators)}" if estimators else ""),
                "baseline": "single-process gcs replay --fast loop",
                "baseline_per_s": round(count / base, 3),
                "ours_per_s": round(count / r["s"], 3),
                "ratio": round(base / r["s"], 2),
                "unit": "flights/s",
                "cluster_start_s": round(r["start_s"], 1),
                "peak_rss_worker_mib": round(r["rss"], 1),
            }
        )
    return rows


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10)
    parser.add_argument("--flights", type=int, default=16)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4])
    parser.add_argument("--estimator", "-e", action="append")
    parser.add_argument("--quick", action="store_true", help="16 flights of 1 minute")
    args = parser.parse_args()
    for row in main(1 if args.quick else args.minutes, args.flights, tuple(args.workers), args.estimator):
        print(row)
