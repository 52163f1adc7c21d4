"""uvicorn ticks once a second in the dashboard (gcs.server.uvicorn_server): its once-a-second
work still runs (the Date header follows the clock), and a stop does not wait for the next tick
(here 60 s away). A real station, uvicorn and HTTP on loopback."""

from __future__ import annotations

import asyncio
import time

import httpx
from live import dashboard, running_station

from gcs.server import uvicorn_server
from gcs.server.dashboard import DashboardServer


def test_the_date_header_follows_the_clock(udp_port):
    async def go() -> tuple[str, str]:
        async with (
            running_station(f"udpin:127.0.0.1:{udp_port}") as station,
            dashboard(station, viser=False) as server,
            httpx.AsyncClient(base_url=f"http://127.0.0.1:{server.port}") as api,
        ):
            first = (await api.get("/api/status")).headers["date"]
            async with asyncio.timeout(5):  # it changes every second
                while (date := (await api.get("/api/status")).headers["date"]) == first:
                    await asyncio.sleep(0.2)  # the next poll: the header changes once a second
            return first, date

    first, later = asyncio.run(go())
    assert time.strptime(later, "%a, %d %b %Y %H:%M:%S GMT") > time.strptime(first, "%a, %d %b %Y %H:%M:%S GMT")


def test_a_stop_does_not_wait_for_the_tick(udp_port, monkeypatch):
    monkeypatch.setattr(uvicorn_server, "TICK", 60.0)

    async def go() -> None:
        async with running_station(f"udpin:127.0.0.1:{udp_port}") as station:
            server = DashboardServer(station, port=0, viser=False)
            await server.start()
            async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{server.port}") as api:
                assert (await api.get("/api/status")).status_code == 200
            await asyncio.wait_for(server.stop(), 20)  # far sooner than the 60 s tick

    asyncio.run(go())
