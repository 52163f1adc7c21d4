"""/ws/live latency from the source's send to the viewer's socket, on one clock, with 1 and 20
clients at 200 Hz, with and without a CPU hog.

    python -m bench.ws_latency [--seconds 10] [--only CLIENTS,HOG,NICE]

Every party is its own process, as on a real station: the source (this module's `send`: ATTITUDE
and HIGHRES_IMU at 200 Hz, GPS 5 Hz, HEARTBEAT 1 Hz over UDP, paced by its own clock, writing down
when each ATTITUDE left), `gcs serve` as shipped (3 estimators, recording, the 3-D view), the
readers (bench.ws_readers, 20 clients in one process), the hog (`while True: pass`).
All times are CLOCK_MONOTONIC, so per onboard sample:
- `server`: source send → the kernel puts the frame in the reader's socket. The figure to hold
  against the target: the UDP queue, the estimation, the frame interval, the per-client send;
  When the reader is behind, the kernel merges queued sends and stamps them with the last one's
  time (bench.ws_readers): `server` is then an upper bound; `server_exact` is the same over the
  frames found with nothing queued behind them (`exact_pct` of all);
- `queue`: send → the frame's flush (its server_time), and `send path`: flush → reader's socket;
- `reader`: the reader process getting to the frame, the bench's own lateness (on this 2-core
  machine 20 readers wait for a core as the station does; a real viewer is a browser, often on
  another machine), and `seen` = send → reader, the previous version's figure.
Beside them, from /proc schedstat (bench.sched), the % of the window each process spent runnable
but waiting for a core (`wait`) and running (`cpu`): the station's event-loop thread, the readers, the hog.
The last configuration runs the station at nice −5 (`gcs serve --nice -5`) when this machine
permits it.

Baseline `Mission Planner 5 Hz push`: Mission Planner's web/WebSocket server pushes its state
every 200 ms, so a sample waits up to 200 ms (100 ms on average) before it even leaves.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from typing import Any

import numpy as np
import psutil

from bench.sched import Sched, process_sched, thread_sched
from bench.serve_cpu import http_json, stream_message, wait_until_serving
from gcs.runtime.priority import RAISED_NICE
from gcs.transport.address import free_port

MISSION_PLANNER_PERIOD_MS = 200.0
RATE_HZ = 200
#: Vehicle time of the first message (ms): far from 0, as a vehicle that booted a while ago.
BOOT_MS = 10_000
CONFIGURATIONS = ((1, False, 0), (20, False, 0), (20, True, 0), (20, True, RAISED_NICE))


def send(port: int, seconds: float) -> list[tuple[int, float]]:
    """The source: the stream for `seconds`, each message at its time; returns every ATTITUDE's
    (time_boot_ms, CLOCK_MONOTONIC s just after its sendto)."""
    from gcs.mavlink.dialect import Encoder  # the source's process only

    enc = Encoder(1, 1)
    schedule: list[tuple[float, str, int]] = []
    for name, hz in (("HIGHRES_IMU", RATE_HZ), ("ATTITUDE", RATE_HZ), ("GPS_RAW_INT", 5), ("HEARTBEAT", 1)):
        schedule += [(k / hz, name, BOOT_MS * 1000 + round(k * 1e6 / hz)) for k in range(int(seconds * hz))]
    schedule.sort()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sent: list[tuple[int, float]] = []
    start = time.monotonic()
    for at, name, us in schedule:
        delay = start + at - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        sock.sendto(enc.encode(stream_message(name, us)), ("127.0.0.1", port))
        if name == "ATTITUDE":
            sent.append((us // 1000, time.monotonic()))
    return sent


def percentiles(values: list[float]) -> list[float]:
    """p50, p99 and the maximum, ms."""
    if not values:
        return []
    return [round(float(v), 2) for v in (*np.percentile(values, [50, 99]), max(values))]


def measure(clients: int, seconds: float, hog: bool, nice: int) -> dict[str, Any]:
    port, http = free_port(), free_port()
    with tempfile.TemporaryDirectory() as tmp:
        serve = ["--connect", f"udpin:127.0.0.1:{port}", "--port", str(http), "--record-dir", tmp, "--token", "bench"]
        server = subprocess.Popen(
            [sys.executable, "-m", "gcs", "serve", *serve, *(["--nice", str(nice)] if nice else [])],
            stdout=subprocess.DEVNULL,
        )
        spinner = None
        try:
            base = f"http://127.0.0.1:{http}"
            wait_until_serving(base)
            source = subprocess.Popen(
                [
                    sys.executable,
                    "-c",
                    f"import json, bench.ws_latency as b; print(json.dumps(b.send({port}, {seconds + 12})))",
                ],
                stdout=subprocess.PIPE,
                text=True,
            )
            deadline = time.monotonic() + 60
            while http_json(f"{base}/api/status")["link"]["rates_hz"].get("ATTITUDE", 0) < 0.75 * RATE_HZ:
                if time.monotonic() > deadline:
                    raise RuntimeError("the station did not reach the ATTITUDE rate")
                time.sleep(0.25)
            if hog:  # another process spinning on a core the whole time (as a busy laptop has)
                spinner = subprocess.Popen([sys.executable, "-c", "while True: pass"])
            readers = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "bench.ws_readers",
                    f"ws://127.0.0.1:{http}/ws/live",
                    str(clients),
                    str(seconds),
                ],
                stdout=subprocess.PIPE,
                text=True,
            )
            station = psutil.Process(server.pid)
            cpu0, loop0, t0 = sum(station.cpu_times()[:2]), thread_sched(server.pid), time.monotonic()
            hog0 = process_sched(spinner.pid) if spinner else Sched(0.0, 0.0, 0)
            got = json.loads(readers.communicate(timeout=seconds + 60)[0])
            wall = time.monotonic() - t0
            station_cpu, loop = sum(station.cpu_times()[:2]) - cpu0, thread_sched(server.pid) - loop0
            hogged = (process_sched(spinner.pid) - hog0) if spinner else None
            load = os.getloadavg()[0]
            sent = dict(json.loads(source.communicate(timeout=seconds + 60)[0]))
        finally:
            if spinner is not None:
                spinner.kill()
                spinner.wait()
            server.send_signal(signal.SIGINT)
            server.wait(60)
    rows = [
        (sent[key], kernel, seen, flushed, exact)
        for per_client in got["samples"]
        for t, kernel, seen, flushed, exact in per_client
        if (key := round(1000 * t)) in sent
    ]
    first = got["samples"][0] if got["samples"] else []
    span = (first[-1][0] - first[0][0]) if len(first) > 1 else 0.0
    return {
        "clients": clients,
        "onboard_hz_client_1": round((len(first) - 1) / span, 1) if span else 0.0,
        "samples": len(rows),
        # p50, p99, max (ms)
        "server_ms": percentiles([1000 * (kernel - sent) for sent, kernel, _, _, _ in rows]),
        # the same over the frames read with nothing queued behind them (their kernel time is exact)
        "server_exact_ms": percentiles([1000 * (kernel - sent) for sent, kernel, _, _, exact in rows if exact]),
        "exact_pct": round(100 * sum(r[4] for r in rows) / max(1, len(rows)), 1),
        "queue_ms": percentiles([1000 * (flushed - sent) for sent, _, _, flushed, _ in rows]),
        "send_path_ms": percentiles([1000 * (kernel - flushed) for _, kernel, _, flushed, _ in rows]),
        "reader_ms": percentiles([1000 * (seen - kernel) for _, kernel, seen, _, _ in rows]),
        "seen_ms": percentiles([1000 * (seen - sent) for sent, _, seen, _, _ in rows]),
        # % of the window: CPU, and runnable but waiting for a core
        "station_cpu_pct": round(100 * station_cpu / wall, 1),
        "loop_thread_cpu_wait_pct": [round(100 * loop.cpu_s / wall, 1), round(100 * loop.run_delay_s / wall, 1)],
        "readers_cpu_wait_pct": [round(100 * got["cpu_s"] / wall, 1), round(100 * got["run_delay_s"] / wall, 1)],
        "hog_cpu_wait_pct": [round(100 * hogged.cpu_s / wall, 1), round(100 * hogged.run_delay_s / wall, 1)]
        if hogged
        else None,
        "load_avg_1m": round(load, 2),
    }


def main(seconds: float = 10.0, only: tuple[int, bool, int] | None = None) -> list[dict[str, Any]]:
    rows = []
    for clients, hog, nice in (only,) if only else CONFIGURATIONS:
        if nice < 0 and os.geteuid() != 0:
            print("skipped: raising the station's priority needs root here", file=sys.stderr)
            continue
        r = measure(clients, seconds, hog, nice)
        rows.append(
            {
                "benchmark": f"ws latency, source → socket, {clients} client(s), 200 Hz"
                + (", CPU hog" if hog else "")
                + (f", station at nice {nice}" if nice else ""),
                "baseline": "Mission Planner 5 Hz push",
                "baseline_ms": MISSION_PLANNER_PERIOD_MS,
                **r,
                "ratio_p99": round(r["server_ms"][1] / MISSION_PLANNER_PERIOD_MS, 3) if r["server_ms"] else None,
                "unit": "ms",
            }
        )
    return rows


if __name__ == "__main__":
    if sys.argv[1:2] == ["--send"]:
        print(json.dumps(send(int(sys.argv[2]), float(sys.argv[3]))))
        sys.exit()
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--only", help="one configuration: CLIENTS,HOG(0/1),NICE, e.g. 20,1,0")
    a = parser.parse_args()
    only = None
    if a.only:
        c, h, n = (int(x) for x in a.only.split(","))
        only = (c, bool(h), n)
    for row in main(a.seconds, only):
        print(json.dumps(row))
