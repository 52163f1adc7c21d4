"""Helpers for tests that run the real simulator against the real link over real sockets."""

from __future__ import annotations

import asyncio
import contextlib
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
async def running_station(connect: str, **kwargs):
    station = Station(StationConfig(connect=connect, **kwargs))
    await station.start()
    try:
        yield station
    finally:
        await station.stop()


async def wait_for(predicate, timeout: float, what: str, poll: float = 0.05) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        await asyncio.sleep(poll)
