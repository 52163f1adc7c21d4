"""CPU of the /ws/live fan-out per send, and of the flush interval: the event loop's thread CPU
(`time.thread_time`, far less load-sensitive than wall time) while the live hub gets a point of
each of 4 sources every 5 ms (200 Hz, as ATTITUDE and three estimators), with 0 and N readers
(bench.ws_readers, their own process). µs per send = (loop CPU with N − with 0) / sends, so it
holds each send's share of the frame's encoding and flush (without clients nothing is encoded).

    python -m bench.ws_fanout [--clients 20] [--seconds 8] [--loop asyncio] [--ws websockets] [--shipped]

The station is started without traffic (its link idle): the points are the hub's only work.
Rows: the shipped interval (gcs.server.live.LiveHub.flush_interval) and a fixed 10 ms (the
interval before), each with its frames/s and loop CPU (% of a core); `--shipped` only the first.
The loop is the station's (`gcs.runtime.event_loop`: uvloop where installed) unless `--loop
asyncio`; `--ws` picks uvicorn's WebSocket implementation (`websockets-sansio`, `websockets`,
`wsproto` where installed; `auto` as shipped).
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
PERIOD_S = 0.005


async def measure(clients: int, seconds: float, fixed_interval: float | None, ws: str = "auto") -> dict[str, Any]:
    station = Station(StationConfig(connect=f"udpin:127.0.0.1:{free_port()}", request_streams=False))
    await station.start()
    server = DashboardServer(station, port=0, viser=False, ws_protocol=ws)
    if fixed_interval is not None:
        server.hub.frame_interval = server.hub.max_frame_interval = fixed_interval
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
        if readers is not None:
            await readers.communicate()
    finally:
        handle[0].cancel()
        await server.stop()
        await station.stop()
    kind = type(loop).__module__.split(".")[0]  # uvloop or asyncio
    return {"frames_per_s": frames / wall, "cpu_pct": 100 * cpu / wall, "interval_ms": 1000 * interval, "loop": kind}


def main(
    clients: int = 20, seconds: float = 8.0, loop: str = "station", ws: str = "auto", shipped: bool = False
) -> list[dict[str, Any]]:
    run = asyncio.run if loop == "asyncio" else event_loop.run
    rows = []
    for name, fixed in (("shipped", None), ("fixed 10 ms", 0.010))[: 1 if shipped else 2]:
        idle = run(measure(0, seconds, fixed, ws))
        busy = run(measure(clients, seconds, fixed, ws))
        per_send = 1e4 * (busy["cpu_pct"] - idle["cpu_pct"]) / max(busy["frames_per_s"] * clients, 1e-9)
        rows.append(
            {
                "benchmark": f"ws fan-out, {clients} clients, 4 sources at 200 Hz, interval {name}",
                "loop": busy["loop"],
                "ws": ws,
                "interval_ms": round(busy["interval_ms"], 1),
                "frames_per_s": round(busy["frames_per_s"], 1),
                "loop_cpu_pct": round(busy["cpu_pct"], 2),
                "loop_cpu_pct_no_clients": round(idle["cpu_pct"], 2),
                "cpu_us_per_send": round(per_send, 1),
                "load_avg_1m": round(os.getloadavg()[0], 2),
            }
        )
    return rows


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--clients", type=int, default=20)
    parser.add_argument("--seconds", type=float, default=8.0)
    parser.add_argument("--loop", choices=("station", "asyncio"), default="station")
    parser.add_argument("--ws", default="auto", help="uvicorn's WebSocket implementation")
    parser.add_argument("--shipped", action="store_true", help="the shipped interval only")
    a = parser.parse_args()
    for row in main(a.clients, a.seconds, a.loop, a.ws, a.shipped):
        print(json.dumps(row))
