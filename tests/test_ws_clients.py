"""Many viewers at once over real WebSockets: 19 clients that read and one that never does.
The readers get (nearly) every sample, the stuck client's queue stays capped (its drops are
counted), and neither the link nor the estimation loses anything."""

from __future__ import annotations

import asyncio
import json
import socket
import sys

import websockets
from conftest import ROOT
from live import running_station, wait_for

from gcs.runtime.streams import StreamPlan
from gcs.server.dashboard import DashboardServer
from gcs.server.live import LiveHub

READERS = 19
# Only a ceiling: the readers stop once they hold the measured window's end (the test tells them).
READER_SECONDS = 240.0
# Deadline for the stuck client's queue to overflow. It overflows once its socket and transport
# buffers (~140 kB) are full: seconds at the normal ~40 kB/s of points, but on a loaded 2-core
# machine the station made ~3 kB/s (measured), so filling them took ~45 s; how fast the machine
# is, is not what this test is about.
OVERFLOW_DEADLINE_S = 120.0
# The measured window: ATTITUDE messages the bus delivers (8 s of the 200 Hz stream on a quiet
# machine), a stretch of data however slowly a loaded machine runs; and the deadline for it.
ATTITUDE_WINDOW = 1600
WINDOW_DEADLINE_S = 120.0


def test_twenty_clients_one_stuck(udp_port):
    r = asyncio.run(twenty_clients(udp_port))
    print(f"\n20 clients: {r}")
    assert min(r["reader_share"]) >= 0.95, r
    assert r["stuck_dropped"] > 0 and r["stuck_queued"] <= r["max_frames"], r
    # its first frames went straight to its socket (gcs.server.ws_direct), the rest to its queue
    # once the socket was full: a direct write never blocks or bypasses the queue
    assert r["stuck_direct_writes"] > 0, r
    assert r["estimation_drops"] == 0 and r["lost"] == 0 and r["crc_errors"] == 0 and r["malformed"] == 0, r


async def stuck_client(port: int):
    """A client that never reads, with a tiny receive buffer so the server's socket fills fast."""
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect(("127.0.0.1", port))
    sock.setblocking(False)
    return await websockets.connect(f"ws://127.0.0.1:{port}/ws/live", sock=sock, max_queue=1)


async def twenty_clients(udp_port: int, count: int = ATTITUDE_WINDOW) -> dict:
    plan = StreamPlan(imu_hz=200, attitude_hz=200)
    # The simulator runs in its own process, as a vehicle would: this process is the server's.
    sim = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "gcs",
        "sim",
        "--profile",
        "pixhawk",
        "--script",
        "quad",
        "--link",
        f"udpout:127.0.0.1:{udp_port}",
        stdout=asyncio.subprocess.DEVNULL,
        stderr=asyncio.subprocess.DEVNULL,
    )
    children: list = [sim, None]
    try:
        async with running_station(f"udpin:127.0.0.1:{udp_port}", plan=plan) as station:
            server = DashboardServer(
                station, port=0, viser=False, hub=LiveHub(seconds=60, client_max_frames=100), send_buffer=32 * 1024
            )
            await server.start()
            url = f"ws://127.0.0.1:{server.port}/ws/live"
            try:
                await wait_for(
                    lambda: station.link.stats.rates().get("ATTITUDE", 0) > 50, 60, "ATTITUDE at its requested rate"
                )
                stuck = await stuck_client(server.port)
                await wait_for(lambda: len(server.hub.clients) == 1, 10, "the stuck client connected")
                stuck_feed = next(iter(server.hub.clients.values()))
                # The readers run in their own process, as browsers would: their JSON parsing must
                # not load the server's event loop.
                readers = children[1] = await asyncio.create_subprocess_exec(
                    sys.executable,
                    "-m",
                    "bench.ws_clients",
                    url,
                    str(READERS),
                    str(READER_SECONDS),
                    "--until-from-stdin",
                    cwd=ROOT,
                    stdin=asyncio.subprocess.PIPE,
                    stdout=asyncio.subprocess.PIPE,
                )
                await wait_for(lambda: len(server.hub.clients) == READERS + 1, 60, "20 clients connected")
                # Measure while the stuck client is already dropping (its socket buffers are full).
                await wait_for(
                    lambda: stuck_feed.dropped_points > 0,
                    OVERFLOW_DEADLINE_S,
                    "the stuck client's queue to overflow",
                )
                sub = station.bus.subscribe("test-attitude", types=["ATTITUDE"], maxlen=100_000)
                await wait_for(lambda: sub.delivered >= count, WINDOW_DEADLINE_S, f"{count} ATTITUDE messages")
                sent = {round(m.vehicle_time, 3) for m in sub.drain()}
                sub.close()
                # Each reader stops once it holds the window's end: frames come in order, so what of the
                # window it lacks then was lost, not late.
                received = json.loads((await readers.communicate(f"{max(sent) - 0.001}\n".encode()))[0])
                framing = station.link.stats.framing
                result = {
                    "attitude_sent": len(sent),
                    "reader_share": sorted(
                        round(len(sent & {round(t, 3) for t, *_ in got}) / len(sent), 4) for got in received
                    ),
                    "stuck_dropped": stuck_feed.dropped_points,
                    "stuck_queued": len(stuck_feed.frames),
                    "stuck_direct_writes": stuck_feed.direct_writes,
                    "max_frames": server.hub.client_max_frames,
                    "estimation_drops": sum(s.dropped for s in station.bus.subscriptions() if s.name == "estimation"),
                    "lost": station.link.stats.packets_lost(),
                    "crc_errors": framing.crc_errors,
                    "malformed": framing.malformed,
                }
                await stuck.close()
            finally:
                await server.stop()
    finally:  # never leak a `gcs sim` or the readers, whatever failed
        for child in children:
            if child is not None and child.returncode is None:
                child.kill()
                await child.wait()

    return result
