"""CPU of the /ws/live fan-out per send, and of the flush interval: the event loop's thread CPU
(`time.thread_time`, far less load-sensitive than wall time) while the live hub gets a point of
each of 4 sources every 5 ms (200 Hz, as ATTITUDE and three estimators), with 0 and N readers
(bench.ws_readers, their own process). µs per send = (loop CPU with N − with 0) / sends, so it
holds each send's share of the frame's encoding and flush (without clients nothing is encoded).

    python -m bench.ws_fanout [--clients 20] [--seconds 8] [--loop asyncio] [--ws direct] [--baseline websockets-sansio]

The station is started without traffic (its link idle): the points are the hub's only work, at
the shipped interval (gcs.server.live.LiveHub.flush_interval). Rows: the shipped protocol
(`direct`: frames written straight to each socket, gcs.server.ws_direct) and, in the same run,
the baseline (uvicorn's own sans-I/O protocol, every send through ASGI), each with its frames/s,
loop CPU (% of a core), µs per send and the share of messages written directly. The loop is the
station's (`gcs.runtime.event_loop`: uvloop where installed) unless `--loop asyncio`; `--ws` and
`--baseline` take any `DashboardServer(ws_protocol=...)`: `direct`, or uvicorn's
`websockets-sansio`, `websockets`, `wsproto` (where installed), `auto`.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import time
from typing import Any

from gcs.core.estimation import AttitudePoint
from gcs.runtime import event_loop
from gcs.runtime.station import Station, StationConfig
from gcs.server.dashboard import DashboardServer
from gcs.transport.address import free_port

SOURCES = ("onboard", "dcm", "kf", "ekf")
#: uvicorn's own sans-I/O protocol: every send through ASGI (what "direct" adds to)
BASELINE_WS = "websockets-sansio"
PERIOD_S = 0.005


async def measure(clients: int, seconds: float, ws: str) -> dict[str, Any]:
    station = Station(StationConfig(connect=f"udpin:127.0.0.1:{free_port()}", request_streams=False))
    await station.start()
    server = DashboardServer(station, port=0, viser=False, ws_protocol=ws)
    await server.start()
    loop = asyncio.get_running_loop()
    ticks = 0

    def tick() -> None:
        nonlocal ticks
        ticks += 1
        server.hub.on_points([AttitudePoint(10 + ticks * PERIOD_S, s, 0.1, 0.2, 0.3) for s in SOURCES])
        handle[0] = loop.call_later(PERIOD_S, tick)

    handle = [loop.call_soon(tick)]
    url = f"ws://127.0.0.1:{server.port}/ws/live"
    readers = (
        await asyncio.create_subprocess_exec(
            sys.executable, "-m", "bench.ws_readers", url, str(clients), str(seconds), stdout=subprocess.PIPE
        )
        if clients
        else None
    )
    try:
        while len(server.hub.clients) < clients:
            await asyncio.sleep(0.05)
        await asyncio.sleep(0.5)
        frames0, cpu0, wall0 = server.hub.frames_out, time.thread_time(), time.monotonic()
        await asyncio.sleep(seconds - 2.0)
        frames, cpu, wall = server.hub.frames_out - frames0, time.thread_time() - cpu0, time.monotonic() - wall0
        interval = server.hub.flush_interval()
        feeds = list(server.hub.clients.values())
        direct = sum(f.direct_writes for f in feeds) / max(1, sum(f.sent_messages for f in feeds))
        if readers is not None:
            await readers.communicate()
    finally:
        handle[0].cancel()
        await server.stop()
        await station.stop()
    kind = type(loop).__module__.split(".")[0]  # uvloop or asyncio
    return {
        "frames_per_s": frames / wall,
        "cpu_pct": 100 * cpu / wall,
        "interval_ms": 1000 * interval,
        "loop": kind,
        "direct_share": direct,
    }


def main(
    clients: int = 20, seconds: float = 8.0, loop: str = "station", ws: str = "direct", baseline: str = BASELINE_WS
) -> list[dict[str, Any]]:
    run = asyncio.run if loop == "asyncio" else event_loop.run
    rows = []
    per_send: dict[str, float] = {}
    for kind in (ws, baseline):
        idle = run(measure(0, seconds, kind))
        busy = run(measure(clients, seconds, kind))
        per_send[kind] = 1e4 * (busy["cpu_pct"] - idle["cpu_pct"]) / max(busy["frames_per_s"] * clients, 1e-9)
        rows.append(
            {
                "benchmark": f"ws fan-out, {clients} clients, 4 sources at 200 Hz, ws {kind}",
                "loop": busy["loop"],
                "ws": kind,
                "interval_ms": round(busy["interval_ms"], 1),
                "frames_per_s": round(busy["frames_per_s"], 1),
                "loop_cpu_pct": round(busy["cpu_pct"], 2),
                "loop_cpu_pct_no_clients": round(idle["cpu_pct"], 2),
                "cpu_us_per_send": round(per_send[kind], 1),
                "direct_share": round(busy["direct_share"], 3),
                "load_avg_1m": round(os.getloadavg()[0], 2),
            }
        )
    rows[0]["ratio_to_baseline"] = round(per_send[ws] / max(per_send[baseline], 1e-9), 2)
    return rows


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--clients", type=int, default=20)
    parser.add_argument("--seconds", type=float, default=8.0)
    parser.add_argument("--loop", choices=("station", "asyncio"), default="station")
    parser.add_argument(
        "--ws", default="direct", help="the server's WebSocket protocol (DashboardServer's ws_protocol)"
    )
    parser.add_argument("--baseline", default=BASELINE_WS, help="the protocol measured against it, in the same run")
    a = parser.parse_args()
    for row in main(a.clients, a.seconds, a.loop, a.ws, a.baseline):
        print(json.dumps(row))
