"""Soak: the server runs `--vehicle-seconds` of vehicle time (default 120; the acceptance run is
3600) with raw IMU at 400 Hz from the simulator in its own process, faster than real time with
`--speed` (PX4 profile, HIGHRES_IMU: ArduPilot caps SET_MESSAGE_INTERVAL at 320 Hz), and 5
WebSocket viewers in another process. Reports the growth of the server
process's resident memory after warm-up (the live store is preallocated, so growth means a
leak), link and bus losses, and the server's CPU per 1,000 messages/s.

Baseline `bounded`: the 50 MB growth allowed for an hour of vehicle time.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import time

import psutil

from gcs.runtime.station import Station, StationConfig
from gcs.runtime.streams import StreamPlan
from gcs.server.dashboard import DashboardServer
from gcs.transport.address import free_port

ALLOWED_GROWTH_MB = 50.0
WARMUP_S = 10.0  # wall seconds before the memory baseline


async def soak(vehicle_seconds: float, speed: float, clients: int) -> dict:
    port = free_port()
    station = Station(StationConfig(connect=f"udpin:127.0.0.1:{port}", plan=StreamPlan(imu_hz=400, attitude_hz=50)))
    server = DashboardServer(station, port=0, viser=False)
    await station.start()
    await server.start()
    sim = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "gcs",
        "sim",
        "--profile",
        "px4",
        "--script",
        "quad",
        "--speed",
        str(speed),
        "--link",
        f"udpout:127.0.0.1:{port}",
        stdout=asyncio.subprocess.DEVNULL,
        stderr=asyncio.subprocess.DEVNULL,
    )
    wall = vehicle_seconds / speed
    viewers = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "bench.ws_clients",
        f"ws://127.0.0.1:{server.port}/ws/live",
        str(clients),
        str(wall + 5),
        stdout=asyncio.subprocess.DEVNULL,
    )
    me = psutil.Process()
    try:
        await asyncio.sleep(WARMUP_S)
        rss0, cpu0, packets0, t0 = (
            me.memory_info().rss,
            sum(me.cpu_times()[:2]),
            station.link.stats.framing.packets,
            time.monotonic(),
        )
        peak = rss0
        while time.monotonic() - t0 < wall - WARMUP_S:
            await asyncio.sleep(1.0)
            peak = max(peak, me.memory_info().rss)
        rss1, cpu1, packets1, t1 = (
            me.memory_info().rss,
            sum(me.cpu_times()[:2]),
            station.link.stats.framing.packets,
            time.monotonic(),
        )
        rates = station.link.stats.rates()
        framing = station.link.stats.framing
        estimation_drops = sum(s.dropped for s in station.bus.subscriptions() if s.name == "estimation")
        client_drops = sum(c.dropped_points for c in server.hub.clients.values())
        attached = len(server.hub.clients)
    finally:
        sim.terminate()
        await sim.wait()
        await viewers.wait()
        await server.stop()
        await station.stop()
    msg_rate = (packets1 - packets0) / (t1 - t0)
    cpu_pct = 100 * (cpu1 - cpu0) / (t1 - t0)
    return {
        "vehicle_s": vehicle_seconds,
        "speed": speed,
        "wall_s": round(t1 - t0 + WARMUP_S, 1),
        "clients": attached,
        "imu_hz_vehicle": round(rates.get("HIGHRES_IMU", 0.0) / speed, 1),
        "messages_per_s": round(msg_rate),
        "rss_growth_mb": round((rss1 - rss0) / 2**20, 1),
        "rss_peak_growth_mb": round((peak - rss0) / 2**20, 1),
        "rss_mb": round(rss1 / 2**20, 1),
        "cpu_pct_per_1k_msg_s": round(cpu_pct / (msg_rate / 1000), 1),
        "packets_lost": station.link.stats.packets_lost(),
        "crc_errors": framing.crc_errors,
        "estimation_drops": estimation_drops,
        "client_drops": client_drops,
    }


def main(vehicle_seconds: float = 120.0, speed: float = 2.0, clients: int = 5) -> list[dict]:
    r = asyncio.run(soak(vehicle_seconds, speed, clients))
    return [
        {
            "benchmark": f"soak: 400 Hz IMU, {clients} viewers",
            "baseline": "bounded",
            "baseline_mb": ALLOWED_GROWTH_MB,
            **r,
            "ratio": round(r["rss_growth_mb"] / ALLOWED_GROWTH_MB, 3),
            "unit": "MB",
        }
    ]


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--vehicle-seconds", type=float, default=120.0, help="vehicle time to run (acceptance: 3600)")
    parser.add_argument("--speed", type=float, default=2.0, help="simulator speed vs wall clock (default 2)")
    parser.add_argument("--clients", type=int, default=5)
    args = parser.parse_args()
    for row in main(args.vehicle_seconds, args.speed, args.clients):
        print(row)
