"""Server CPU per `GET /api/status`, against the per-request recomputation it replaced, and the
round trip over HTTP with pages polling.

A station receives the PX4 simulator's stream (HIGHRES_IMU 400 Hz, ATTITUDE 50 Hz; the simulator
in its own process) for 35 s, so every comparison holds its full 30 s history. Then, on the event
loop, the CPU time (`time.thread_time`) of:
- ours: the route handler, which reads the station's last published snapshot, encoded once per
  snapshot (gcs.server.status_body), and encodes its own few fields;
- baseline `encode`: validating and encoding the whole body per request (as before status_body);
- baseline `recompute`: what each request computed before the Station published snapshots
  (link, streams, vehicle and, per estimator, the comparison with its 101-step lag search).
Then the round trip over real HTTP (uvicorn, loopback) by PAGES pages in another process
(bench.status_pages), each polling every POLL_S on its own keep-alive connection (twice a page's
rate, for more samples): p50, p99 and the maximum of request sent → the answer in the page's
socket (`server`: the kernel's receive time) and → read by the page (`seen`: plus the polling
process's own wait), with the % of the window the event loop's thread and the pages' threads
ran and waited for a core (/proc schedstat, bench.sched).
Target: ≤ 5 ms. Ratio = baseline / ours (> 1: we are cheaper).
"""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
import time

from starlette.requests import Request

from bench.loop_trace import LoopTrace
from bench.sched import thread_sched
from bench.ws_latency import percentiles
from gcs.runtime.station import Station, StationConfig
from gcs.runtime.streams import StreamPlan
from gcs.server.dashboard import DashboardServer
from gcs.server.json_body import encode
from gcs.server.routers.status import get_status
from gcs.server.status_body import snapshot_status
from gcs.transport.address import free_port

WARMUP_S = 35.0
CALLS = 200
PAGES = 5
POLL_S = 0.5
POLL_FOR_S = 30.0


def cpu_ms_per_call(work, calls: int) -> float:
    started = time.thread_time()
    for _ in range(calls):
        work()
    return 1000 * (time.thread_time() - started) / calls


async def measure(trace: LoopTrace | None = None) -> dict:
    port = free_port()
    station = Station(StationConfig(connect=f"udpin:127.0.0.1:{port}", plan=StreamPlan(imu_hz=400, attitude_hz=50)))
    await station.start()
    sim = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "gcs",
            "sim",
            "--profile",
            "px4",
            "--script",
            "quad",
            "--link",
            f"udpout:127.0.0.1:{port}",
        ],
        stdout=subprocess.DEVNULL,
    )
    server = DashboardServer(station, port=0, viser=False)
    await server.start()
    try:
        await asyncio.sleep(WARMUP_S)
        app = server._server.config.app if server._server else None
        scope = {"type": "http", "app": app, "headers": [], "query_string": b"", "path": "/api/status"}
        request = Request({**scope, "scheme": "http", "server": ("127.0.0.1", server.port)})

        def ours() -> None:
            coroutine = get_status(request, station, server.hub)
            try:
                coroutine.send(None)  # the handler never awaits: run it to completion here
            except StopIteration:
                pass

        def encode_per_request() -> None:
            encode(snapshot_status(station.snapshot))

        def recompute() -> None:
            station.link.snapshot()
            station.streams.snapshot()
            station.vehicle.snapshot()
            station.estimation.snapshot(time.monotonic())

        new = cpu_ms_per_call(ours, CALLS)
        encoded = cpu_ms_per_call(encode_per_request, CALLS)
        # the whole request over real HTTP (uvicorn, FastAPI, JSON), from another process
        client = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "bench.status_pages", f"http://127.0.0.1:{server.port}/api/status",
            str(PAGES), str(POLL_S), str(POLL_FOR_S),
            stdout=subprocess.PIPE,
        )  # fmt: skip
        if trace is not None:
            trace.install(asyncio.get_running_loop())
            trace.recording = True
        loop0, t0 = thread_sched(), time.monotonic()
        pages = json.loads((await client.communicate())[0])
        loop, wall = thread_sched() - loop0, time.monotonic() - t0
        if trace is not None:
            trace.uninstall()
        old = cpu_ms_per_call(recompute, max(10, CALLS // 10))
        imu_hz = station.link.stats.rates().get("HIGHRES_IMU", 0.0)
    finally:
        await server.stop()
        await station.stop()
        sim.terminate()
        sim.wait(10)
    return {
        "ours_ms": round(new, 3),
        "encode_ms": round(encoded, 3),
        "baseline_ms": round(old, 2),
        "imu_hz": round(imu_hz),
        "server_ms": pages["server_ms"],
        "requests": pages["requests"],
        "seen_ms": pages["seen_ms"],
        # % of the polling window: the event loop's thread running, and runnable but waiting for a core
        "loop_cpu_wait_pct": [round(100 * loop.cpu_s / wall, 1), round(100 * loop.run_delay_s / wall, 1)],
        "pages_cpu_wait_pct": [round(100 * pages["cpu_s"] / wall, 1), round(100 * pages["run_delay_s"] / wall, 1)],
    }


def traced(slowest: int = 10) -> dict:
    """The round trip with the event loop traced (bench.loop_trace): where the slowest requests'
    time went, and the longest callbacks of the window."""
    trace = LoopTrace()
    r = asyncio.run(measure(trace))
    requests = sorted(r["requests"], key=lambda q: q[0] - q[1])
    spans = trace.spans
    callbacks = [s for s in spans if s.kind != "select"]
    return {
        "server_p50_p99_max_ms": percentiles(r["server_ms"]),
        "loop_cpu_wait_pct": r["loop_cpu_wait_pct"],
        "slowest": [trace.explain(sent, answered, port) for sent, answered, port in requests[:slowest]],
        "median_request": trace.explain(*requests[len(requests) // 2]),
        "gc_passes_n_p50_max_ms": {
            kind: [len(ms), *percentiles(ms)[::2]]
            for kind in sorted({s.what for s in spans if s.kind == "gc"})
            if (ms := [1000 * (s.end - s.start) for s in spans if s.what == kind])
        },
        "longest_callbacks": [
            {"ms": round(1000 * (s.end - s.start), 2), "cpu_ms": round(1000 * s.cpu, 2), "what": s.what}
            for s in sorted(callbacks, key=lambda s: s.start - s.end)[:15]
        ],
        "load_avg_1m": round(os.getloadavg()[0], 2),
    }


def main() -> list[dict]:
    r = asyncio.run(measure())
    return [
        {
            "benchmark": f"GET /api/status CPU per request ({r['imu_hz']} Hz IMU, 30 s history)",
            "ours": r["ours_ms"],
            "baseline": "recompute per request",
            "baseline_value": r["baseline_ms"],
            "ratio": round(r["baseline_ms"] / max(r["ours_ms"], 1e-6), 1),
            "unit": "ms CPU",
            "target": "< 5 ms",
        },
        {
            "benchmark": "GET /api/status CPU per request, against validating and encoding the body per request",
            "ours": r["ours_ms"],
            "baseline": "encode per request",
            "baseline_value": r["encode_ms"],
            "ratio": round(r["encode_ms"] / max(r["ours_ms"], 1e-6), 1),
            "unit": "ms CPU",
        },
        {
            "benchmark": f"GET /api/status over HTTP, round trip ({PAGES} pages polling every {POLL_S} s, loopback)",
            # request sent → the answer in the page's socket (the server), and → read by the page
            "server_p50_p99_max_ms": percentiles(r["server_ms"]),
            "seen_p50_p99_max_ms": percentiles(r["seen_ms"]),
            "requests": len(r["server_ms"]),
            "loop_cpu_wait_pct": r["loop_cpu_wait_pct"],
            "pages_cpu_wait_pct": r["pages_cpu_wait_pct"],
            "unit": "ms wall",
            "target": "≤ 5 ms",
            "load_avg_1m": round(os.getloadavg()[0], 2),
        },
    ]


if __name__ == "__main__":
    if sys.argv[1:] == ["--trace"]:
        print(json.dumps(traced(), indent=1))
    else:
        print(main())
