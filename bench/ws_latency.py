"""Latency from a packet's arrival at the link (Message.host_time) to its sample reaching a
WebSocket client, p50/p95/p99, with ATTITUDE and raw IMU at 200 Hz from the simulator, for 1
and 20 clients (in a separate process). Split at the frame's flush (its server_time): `queue`
is arrival → flush (estimation, the hub's frame interval), `delivery` flush → received (the
per-client sends, the kernel, the client process's own turn on a core).
The last configuration runs the station at a raised priority (`gcs serve --nice -5`) (gcs.runtime.priority) when
this machine permits it; the simulator, the clients and the hog stay at nice 0.
GCS_BENCH_PROBE=1: the event loop's slow callbacks and answer delay (bench.loop_stalls.Probe)
are printed for each configuration.

Baseline `Mission Planner 5 Hz push`: Mission Planner's web/WebSocket server pushes its state
every 200 ms, so a sample waits up to 200 ms (100 ms on average) before it even leaves.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import sys
import time

import numpy as np
import psutil

from bench.loop_stalls import Probe
from gcs.runtime.priority import RAISED_NICE, raise_priority
from gcs.runtime.station import Station, StationConfig
from gcs.runtime.streams import StreamPlan
from gcs.server.dashboard import DashboardServer
from gcs.transport.address import free_port

MISSION_PLANNER_PERIOD_MS = 200.0


def normal_priority() -> None:
    """A child's nice back to 0 (a station that raised its own priority raised theirs too)."""
    os.setpriority(os.PRIO_PROCESS, 0, 0)


async def measure(clients: int, seconds: float, hog: bool = False, probe: Probe | None = None) -> dict:
    port = free_port()
    station = Station(StationConfig(connect=f"udpin:127.0.0.1:{port}", plan=StreamPlan(imu_hz=200, attitude_hz=200)))
    server = DashboardServer(station, port=0, viser=False)
    await station.start()
    # the vehicle in its own process, as a real one is (in this loop it took the station's turns)
    sim = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "gcs", "sim", "--profile", "pixhawk", "--script", "quad",
        "--link", f"udpout:127.0.0.1:{port}",
        stdout=asyncio.subprocess.DEVNULL, preexec_fn=normal_priority,
    )  # fmt: skip
    await server.start()
    arrivals: dict[float, float] = {}
    spinner = None
    try:
        while station.link.stats.rates().get("ATTITUDE", 0) < 150:  # streams at 200 Hz
            await asyncio.sleep(0.2)
        sub = station.bus.subscribe("bench-arrival", types=["ATTITUDE"], maxlen=100_000)
        # a CPU hog: another process spinning on a core the whole time (as a busy laptop has)
        spinner = (
            await asyncio.create_subprocess_exec(sys.executable, "-c", "while True: pass", preexec_fn=normal_priority)
            if hog
            else None
        )
        proc = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "bench.ws_clients",
            f"ws://127.0.0.1:{server.port}/ws/live",
            str(clients),
            str(seconds),
            stdout=asyncio.subprocess.PIPE,
            preexec_fn=normal_priority,
        )
        reader = asyncio.create_task(proc.communicate())
        if probe is not None:
            probe.reset()
        readers, readers_cpu = psutil.Process(proc.pid), 0.0
        cpu0, t0 = time.process_time(), time.monotonic()
        while not reader.done():
            for m in sub.drain():
                arrivals[round(m.vehicle_time, 3)] = m.host_time
            with contextlib.suppress(psutil.Error):  # its last figure before it exits
                readers_cpu = sum(readers.cpu_times()[:2])
            await asyncio.sleep(0.05)
        station_cpu, wall = time.process_time() - cpu0, time.monotonic() - t0
        received = json.loads(reader.result()[0])
        sub.close()
        rate = station.link.stats.rates().get("ATTITUDE", 0.0)
    finally:
        if spinner is not None:
            spinner.kill()
            await spinner.wait()
        await server.stop()
        sim.kill()
        await sim.wait()
        await station.stop()
    pairs = [
        (1000 * (recv - arrivals[round(t, 3)]), 1000 * (recv - flushed))
        for per_client in received
        for t, recv, flushed in per_client
        if round(t, 3) in arrivals
    ]
    latencies = [total for total, _ in pairs]
    p50, p95, p99 = (float(v) for v in np.percentile(latencies, [50, 95, 99]))
    queue = np.percentile([total - delivery for total, delivery in pairs], [50, 99])
    delivery = np.percentile([delivery for _, delivery in pairs], [50, 99])
    return {
        "clients": clients,
        "attitude_hz": round(rate, 1),
        "samples": len(latencies),
        "p50_ms": round(p50, 2),
        "p95_ms": round(p95, 2),
        "p99_ms": round(p99, 2),
        "max_ms": round(max(latencies), 2),
        "queue_p50_p99_ms": [round(float(v), 2) for v in queue],
        "delivery_p50_p99_ms": [round(float(v), 2) for v in delivery],
        # % of a core: this process (the station and the server) and the readers' process
        "station_cpu_pct": round(100 * station_cpu / wall, 1),
        "readers_cpu_pct": round(100 * readers_cpu / wall, 1),
        "load_avg_1m": round(os.getloadavg()[0], 2),
    }


def main(seconds: float = 10.0) -> list[dict]:
    rows = []
    for clients, hog, nice in ((1, False, 0), (20, False, 0), (20, True, 0), (20, True, RAISED_NICE)):
        priority = raise_priority(nice)
        if os.getpriority(os.PRIO_PROCESS, 0) != nice:
            print(f"skipped: {priority}", file=sys.stderr)
            continue
        probe = Probe() if os.environ.get("GCS_BENCH_PROBE") else None
        if probe is not None:
            probe.install()
        r = asyncio.run(measure(clients, seconds, hog, probe))
        normal_priority()
        if probe is not None:
            probe.uninstall()
            print(json.dumps(probe.report(), indent=1), file=sys.stderr)
        rows.append(
            {
                "benchmark": f"ws latency, {clients} client(s), 200 Hz"
                + (", CPU hog" if hog else "")
                + (f", station at nice {nice}" if nice else ""),
                "baseline": "Mission Planner 5 Hz push",
                "baseline_ms": MISSION_PLANNER_PERIOD_MS,
                **r,
                "ratio_p99": round(r["p99_ms"] / MISSION_PLANNER_PERIOD_MS, 3),
                "unit": "ms",
            }
        )
    return rows


if __name__ == "__main__":
    for row in main():
        print(row)
