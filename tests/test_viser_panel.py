"""viser has no authentication, so its panel must change nothing: a real viser client (viser's own
web page in Chromium, no token) types into and clicks every control it is shown, and no gain moves;
the panel still follows a change made with the token, in the gain's own units (not its log10)."""

from __future__ import annotations

import asyncio
import os

import httpx
import pytest
from conftest import free_port
from live import CHROMIUM, CHROMIUM_ARGS, running_station, sim_process
from playwright.async_api import Error as PlaywrightError
from playwright.async_api import async_playwright

from gcs.server.dashboard import DashboardServer


def test_viser_panel_changes_nothing(udp_port, artifacts_dir):
    if not os.path.exists(CHROMIUM):
        pytest.fail(f"{CHROMIUM} missing: run bash .ci/setup")
    asyncio.run(asyncio.wait_for(scenario(udp_port, artifacts_dir), 240))


async def scenario(udp_port: int, artifacts_dir) -> None:
    async with (
        running_station(f"udpin:127.0.0.1:{udp_port}") as station,
        sim_process(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad"),
    ):
        server = DashboardServer(station, port=0, viser_port=free_port())
        await server.start()
        estimators = station.estimation.pipeline.estimators
        try:
            async with async_playwright() as pw:
                browser = await pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
                page = await browser.new_page(viewport={"width": 1366, "height": 768})
                await page.goto(f"http://127.0.0.1:{server.viser_port}/")
                # The panel starts minimized (it must not cover the vehicle): open it as a user does.
                await page.get_by_text("gcs pose").first.click(timeout=60_000)
                await page.get_by_text("Estimator gains").click(timeout=60_000)
                await page.get_by_text("Read-only here").wait_for(timeout=30_000)
                before = {n: dict(e.gains.values) for n, e in estimators.items()}

                touched = await touch_every_control(page)
                assert touched > 0, "the viser page showed no controls at all: the client did not load"

                # A change with the token (the page's way) still reaches the panel, in real units.
                async with httpx.AsyncClient(
                    base_url=f"http://127.0.0.1:{server.port}", headers=server.auth_headers
                ) as api:
                    ok = await api.put("/api/estimators/dcm/gains/kp_rp", json={"value": 0.3125})
                    assert ok.status_code == 200, ok.text
                await page.get_by_text("0.3125").first.wait_for(timeout=30_000)
                await page.screenshot(path=str(artifacts_dir / "viser-panel.png"))
                await browser.close()
            after = {n: dict(e.gains.values) for n, e in estimators.items()}
            before["dcm"]["kp_rp"] = 0.3125
            assert after == before
            assert not [e for e in station.events.recent if e.client == "viser"]
            assert server.viser._share_tunnel is None  # nobody published the view through viser's relay
        finally:
            await server.stop()


async def touch_every_control(page) -> int:
    """Type a number into every input and click every button and slider viser shows; count the
    controls that took it (a notification's close button may be gone by then)."""
    touched = 0
    for box in await page.locator("input").all():
        try:
            if await box.is_editable():
                await box.fill("5", timeout=2_000)
                await box.press("Enter", timeout=2_000)
            else:
                await box.click(timeout=2_000, force=True)
            touched += 1
        except PlaywrightError:  # gone or hidden before the click
            pass
    for control in await page.locator("button, [role=slider]").all():
        try:
            await control.click(timeout=2_000, force=True)
            touched += 1
        except PlaywrightError:  # gone or hidden before the click
            pass
    return touched
