"""Helpers for tests that run the real simulator against the real link over real sockets."""

from __future__ import annotations

import asyncio
import contextlib
import subprocess
import sys
import time

from gcs.runtime.station import Station, StationConfig
from gcs.sim import SimVehicle


@contextlib.asynccontextmanager
async def running_sim(address: str, profile: str = "apm25", **kwargs):
    sim = SimVehicle(profile=profile, **kwargs)
    task = asyncio.create_task(sim.run(address))
    try:
        yield sim
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)


@contextlib.asynccontextmanager
async def sim_process(address: str, profile: str = "pixhawk", script: str = "quad", speed: float = 1.0):
    """The simulator as `gcs sim` in a process of its own. Scenarios with a browser use it: the
    test's event loop then carries only the station, the server and Playwright, and a loaded
    machine slows the page, never the vehicle's clock (one loop for all of them fell behind for
    good at load 8-12 on two cores)."""
    command = [sys.executable, "-m", "gcs", "sim", "--profile", profile, "--script", script]
    proc = subprocess.Popen(
        [*command, "--speed", str(speed), "--link", address], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        yield proc
    finally:
        stop_process(proc)


def stop_process(proc: subprocess.Popen, timeout: float = 10.0) -> None:
    """SIGTERM, then SIGKILL after `timeout` s: a test never leaves its child running."""
    proc.terminate()
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


@contextlib.asynccontextmanager
async def running_station(connect: str, **kwargs):
    station = Station(StationConfig(connect=connect, **kwargs))
    await station.start()
    try:
        yield station
    finally:
        await station.stop()


@contextlib.asynccontextmanager
async def served_api(station: Station):
    """The station's dashboard server on a free port and an authorised HTTP client to it."""
    import httpx

    from gcs.server.dashboard import DashboardServer

    server = DashboardServer(station, port=0, viser=False)
    await server.start()
    try:
        async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{server.port}", headers=server.auth_headers) as api:
            yield api
    finally:
        await server.stop()


async def wait_for(predicate, timeout: float, what: str, poll: float = 0.05) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        await asyncio.sleep(poll)
