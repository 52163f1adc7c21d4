"""The dashboard's Protocol tab in headless Chromium: start seed 000's bench protocol from the
page, the simulated vehicle performs the first step, the page shows the next prompt and the
first step's figures, and stops the run. Before any run its run buttons are disabled."""

from __future__ import annotations

import asyncio

from live import running_sim, running_station, wait_for
from playwright.async_api import async_playwright
from test_dashboard_panels import _chromium_installed, open_page  # noqa: F401 - the fixture fails without Chromium

from gcs.server.dashboard import DashboardServer

RUN_BUTTONS_DISABLED = (
    "['protocol-skip', 'protocol-repeat', 'protocol-stop'].map((id) => document.getElementById(id).disabled)"
)


def test_protocol_panel(udp_port, artifacts_dir):
    asyncio.run(asyncio.wait_for(_scenario(udp_port, artifacts_dir), 240))


async def _scenario(udp_port: int, artifacts_dir) -> None:
    errors: list[str] = []
    async with running_station(f"udpin:127.0.0.1:{udp_port}") as station:
        server = DashboardServer(station, port=0, viser=False)
        await server.start()
        try:
            async with async_playwright() as pw:
                browser, page = await open_page(pw, server.url, errors)
                await page.click("#tabs button[data-tab=protocol]")
                await page.wait_for_function("() => document.querySelector('#protocol-name').options.length >= 2")
                # no run yet: skip, repeat and stop have nothing to act on (each was a 404 to click)
                assert await page.text_content("#protocol-prompt") == "no protocol run yet"
                assert await page.evaluate(RUN_BUTTONS_DISABLED) == [True, True, True]
                await page.select_option("#protocol-name", "seed000-bench")
                await page.fill("#protocol-detect", "truth")
                await page.click("#protocol-start")
                await page.wait_for_function(
                    "() => document.querySelector('#protocol-prompt').textContent.includes('roll -30')"
                )
                # the vehicle starts now, so its bench script begins with the first step's angle
                async with running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="bench"):
                    await wait_for(lambda: station.protocol.index >= 1, 90, "the first step held")
                    prompt = "document.querySelector('#protocol-prompt').textContent"
                    step2 = f"() => {prompt}.startsWith('Step 2: rotate to roll -45')"
                    await page.wait_for_function(step2, timeout=30_000)
                row = page.locator("#protocol-table tr[data-step='1']")
                await row.wait_for(timeout=30_000)
                headers = await page.locator("#protocol-table th").all_inner_texts()
                cells = await row.locator("td").all_inner_texts()
                shown = dict(zip(headers, cells))
                assert shown["step"] == "roll -30" and float(shown["truth"]) < 0.5
                assert {"dcm", "kf", "ekf", "onboard"} <= set(shown)
                assert await page.locator("#protocol-progress").get_attribute("value") is not None
                await page.click("#protocol-stop")
                await page.wait_for_function(
                    "() => document.querySelector('#protocol-prompt').textContent === 'protocol stopped'"
                )
                await page.screenshot(path=str(artifacts_dir / "protocol_panel.png"))
                await browser.close()
        finally:
            await server.stop()
    assert station.protocol is not None and station.protocol.ended
    assert not errors, errors
