"""Everything that touches live state runs on the event loop: every route and dependency is a
coroutine, 200 gain changes over REST at 400 Hz IMU all land on the loop thread, and replaying
the recorded session reproduces the live outputs exactly, gain changes included."""

from __future__ import annotations

import asyncio
import importlib
import inspect
import subprocess
import sys
import threading

import httpx
import numpy as np
from conftest import free_port
from fastapi.dependencies.models import Dependant
from fastapi.routing import APIRoute, APIWebSocketRoute
from live import running_station, wait_for

from gcs.runtime.replay import ReplaySession
from gcs.runtime.station import Station, StationConfig
from gcs.runtime.streams import StreamPlan
from gcs.server.app import create_app
from gcs.server.dashboard import DashboardServer
from gcs.server.routers import ROUTERS
from gcs.sessions import layout
from gcs.sessions.sources import open_source

GCS = [sys.executable, "-m", "gcs"]
#: (estimator, gain, two values to alternate between)
CHANGES = [("dcm", "kp_rp", (0.15, 0.35)), ("ekf", "gyro_noise", (0.004, 0.008)), ("kf", "q_roll", (0.02, 0.05))]


def dependency_calls(dependant: Dependant) -> list:
    calls = []
    for sub in dependant.dependencies:
        calls.append(sub.call)
        calls += dependency_calls(sub)
    return calls


def test_every_route_and_dependency_is_a_coroutine():
    """A plain `def` route or dependency would run in Starlette's thread pool, off the loop."""
    create_app(Station(StationConfig(connect="udpin:127.0.0.1:0")), token="t")  # every router, as the app has them
    routers = [importlib.import_module(module).router for module in ROUTERS]
    routes = [r for router in routers for r in router.routes if isinstance(r, APIRoute | APIWebSocketRoute)]
    assert len(routes) > 25
    for route in routes:
        assert inspect.iscoroutinefunction(route.endpoint), f"{route.path}: {route.endpoint.__name__} is not async"
        for call in dependency_calls(route.dependant):
            assert inspect.iscoroutinefunction(call), f"{route.path}: dependency {call} is not async"


def test_gain_changes_at_400_hz_land_on_the_loop_and_replay_reproduces_live(tmp_path):
    port = free_port()
    live: list = []
    threads: list[int] = []

    async def record() -> tuple[int, object]:
        plan = StreamPlan(imu_hz=400, attitude_hz=50)
        async with running_station(
            f"udpin:127.0.0.1:{port}", sessions_dir=str(tmp_path), record=True, plan=plan
        ) as station:
            loop_thread = threading.get_ident()
            set_gain = station.set_gain

            def spy(*args, **kwargs):
                threads.append(threading.get_ident())
                return set_gain(*args, **kwargs)

            station.set_gain = spy  # type: ignore[method-assign]
            station.estimation.points.connect(live.extend)
            sim = subprocess.Popen(
                [*GCS, "sim", "--profile", "px4", "--script", "quad", "--link", f"udpout:127.0.0.1:{port}"],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
            )
            server = DashboardServer(station, port=0, viser=False)
            await server.start()
            try:
                pipeline = station.estimation.pipeline
                await wait_for(lambda: station.link.stats.rates().get("HIGHRES_IMU", 0) > 300, 60, "400 Hz IMU")
                async with httpx.AsyncClient(
                    base_url=f"http://127.0.0.1:{server.port}", timeout=30, headers=server.auth_headers
                ) as api:
                    for i in range(200):
                        estimator, gain, values = CHANGES[i % len(CHANGES)]
                        url = f"/api/estimators/{estimator}/gains/{gain}"
                        response = await api.put(url, json={"value": values[(i // len(CHANGES)) % 2]})
                        assert response.status_code == 200, response.text
                imu_at_end = pipeline.imu_samples
                # a second of IMU after the last change, and a run long enough for the comparison below
                # (the 200 changes alone can take under 2 s: 3 estimates per IMU sample, over 10,000 points)
                enough = max(imu_at_end + 400, 3_600)
                await wait_for(lambda: pipeline.imu_samples > enough, 60, "IMU after the changes")
            finally:
                await server.stop()
                sim.terminate()
                sim.wait(10)
            return loop_thread, station.recorder.session.folder

    loop_thread, folder = asyncio.run(record())
    assert len(threads) == 200 and set(threads) == {loop_thread}

    events = [line for line in (folder / layout.EVENTS).read_text().splitlines() if '"kind": "gain"' in line]
    assert len(events) >= 190  # a change to the value already set records nothing

    replayed: list = []
    session = ReplaySession(open_source(folder), speed=0)
    session.points.connect(replayed.extend)
    session.run_to_end()
    assert len(live) > 10_000
    assert [p.source for p in replayed] == [p.source for p in live]
    as_array = lambda points: np.array([(p.t, p.roll, p.pitch, p.yaw) for p in points])  # noqa: E731
    np.testing.assert_array_equal(as_array(replayed), as_array(live))
