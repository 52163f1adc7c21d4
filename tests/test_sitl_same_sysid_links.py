"""The real ArduPlane and ArduCopter SITL (../shared/sitl), both at their default system id 1, each
on a link of its own (`gcs serve --connect tcp:... --connect tcp:...`, as an engineer brings up two
simulators or two airframes). The station serves a system id on the first link it hears it on only,
so the second vehicle is not served; before, nothing but an "also heard" line in events.jsonl said
so: /api/vehicles listed one vehicle, the page warned of nothing and `gcs status` printed one
vehicle's report. The page's warnings, /api/status and `gcs status` now name the other vehicle
(its link and MAV_TYPE) and ask for a system id each."""

from __future__ import annotations

import asyncio
import socket

import httpx
import pytest
from live import POLL_MS, launch_chromium, open_page, wait_for
from playwright.async_api import async_playwright
from test_sitl_copter import sitl_process

from gcs.commands.status import format_report
from gcs.runtime.fleet import Fleet
from gcs.runtime.station import StationConfig
from gcs.server.dashboard import DashboardServer

pytestmark = pytest.mark.slow


def bound(port: int) -> bool:
    """Whether something listens on TCP `port` (binding it fails)."""
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return True
    return False


@pytest.mark.timeout(300)
def test_a_second_vehicle_at_the_same_system_id_on_another_link_is_named(tmp_path):
    errors: list[str] = []

    async def scenario(plane: int, copter: int):
        links = [f"tcp:127.0.0.1:{plane}", f"tcp:127.0.0.1:{copter}"]
        fleet = Fleet(StationConfig(connect=links[0], estimate=False), links)
        server = DashboardServer(fleet.first, port=0, viser=False, fleet=fleet)
        await fleet.start()
        await server.start()
        try:
            first = fleet.first
            await wait_for(lambda: first.vehicle.vehicle_type, 90, "the first vehicle's heartbeat")

            def also_heard() -> bool:  # the other one's heartbeat, on the other link
                return any(e.kind == "vehicle" and e.data.get("event") == "also heard" for e in first.events.recent)

            await wait_for(also_heard, 90, "the second vehicle's heartbeat on the other link")
            async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{server.port}") as api:
                vehicles = (await api.get("/api/vehicles")).json()
                first.publish()
                status = (await api.get("/api/status")).json()
            assert status["vehicle"].get("others"), status["vehicle"]  # before: not a word of it
            async with async_playwright() as pw:
                browser = await launch_chromium(pw)
                page = await open_page(browser, errors)
                await page.goto(server.url)
                warning = (
                    "document.getElementById('warnings').textContent.includes('another vehicle sends as system 1')"
                )
                await page.wait_for_function(warning, polling=POLL_MS, timeout=60_000)
                shown = await page.evaluate("document.getElementById('warnings').textContent")
            return vehicles, status, format_report(first.publish()), shown
        finally:
            await server.stop()
            await fleet.stop()

    with sitl_process(tmp_path / "plane", "arduplane", "plane", "plane.parm", 1) as plane:
        asyncio.run(wait_for(lambda: bound(plane), 30, "the plane's port (the next SITL picks another)"))
        with sitl_process(tmp_path / "copter", "arducopter", "+", "copter.parm", 1) as copter:
            vehicles, status, report, shown = asyncio.run(scenario(plane, copter))
    assert not errors, errors
    assert len(vehicles) == 1, vehicles  # one system id: one vehicle served
    served = vehicles[0]
    other = "MAV_TYPE_QUADROTOR" if served["vehicle_type"] == "MAV_TYPE_FIXED_WING" else "MAV_TYPE_FIXED_WING"
    other_link = next(link for link in (f"tcp:127.0.0.1:{p}" for p in (plane, copter)) if link != served["link"])
    assert status["vehicle"]["others"] == [f"{other_link} ({other})"], status["vehicle"]
    assert f"another vehicle sends as system 1 on {other_link} ({other})" in shown, shown
    assert f"ANOTHER VEHICLE SENDS AS THIS SYSTEM on {other_link} ({other})" in report, report
