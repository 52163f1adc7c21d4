"""The dashboard's number boxes in headless Chromium (Debian's /usr/bin/chromium, driven by
Playwright) against the real server under uvicorn: an emptied box is no value (not a write of 0)."""

from __future__ import annotations

import asyncio

from live import POLL_MS, dashboard, launch_chromium, open_dashboard, open_page, running_sim, running_station, wait_for
from playwright.async_api import async_playwright

# dcm's dip tolerance, [0 … 3.142] rad: 0 is a value it takes
GAIN_BOX = "#gains details:has(summary[data-estimator=dcm]) input[type=number][data-gain=mag_dip_tol]"
PARAM_BOX = "tr.tune-edit[data-param=ATC_RAT_RLL_P] input[type=number]"


async def empty_box(page, selector: str) -> None:
    """Clear a box and leave it (Tab), as a person does: the browser fires `change` with value ""."""
    box = page.locator(selector)
    await box.fill("")
    await box.press("Tab")


def test_emptied_boxes_write_nothing(udp_port):
    asyncio.run(asyncio.wait_for(emptied_boxes_scenario(udp_port), 240))


async def emptied_boxes_scenario(udp_port: int) -> None:
    errors: list[str] = []
    async with (
        running_station(f"udpin:127.0.0.1:{udp_port}") as station,
        running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad") as sim,
        dashboard(station, viser=False) as server,
    ):
        await wait_for(lambda: station.link.target_system is not None, 30, "the vehicle's heartbeat")
        async with async_playwright() as pw:
            browser = await launch_chromium(pw)
            page = await open_page(browser, errors)
            await open_dashboard(page, server.url, f"document.querySelector('{GAIN_BOX}') !== null")
            held = await page.input_value(GAIN_BOX)
            assert held == "0.174533", held

            # A gain's box emptied: the gain is kept and the box shows it again (it was set to 0).
            await empty_box(page, GAIN_BOX)
            await page.wait_for_function(
                f"document.querySelector('{GAIN_BOX}').value !== ''", polling=POLL_MS, timeout=20_000
            )
            gains = await page.evaluate(
                "fetch('/api/estimators').then((r) => r.json()).then((es) =>"
                " es.find((e) => e.name === 'dcm').gains.find((g) => g.name === 'mag_dip_tol').value)"
            )
            assert abs(gains - 0.17453292519943295) < 1e-9, gains
            assert await page.input_value(GAIN_BOX) == held

            # A vehicle parameter's box emptied: no write is asked for (it was a write of 0).
            await page.click("#tabs button[data-tab=tuning]")
            download = page.locator("#param-download-btn")
            await download.wait_for(state="visible", timeout=30_000)
            await download.click()
            await page.wait_for_function(
                f"document.querySelector('{PARAM_BOX}') && document.querySelector('{PARAM_BOX}').value !== ''",
                polling=POLL_MS,
                timeout=30_000,
            )
            before = await page.input_value(PARAM_BOX)
            await empty_box(page, PARAM_BOX)
            await page.wait_for_function(
                f"document.querySelector('{PARAM_BOX}').value !== ''", polling=POLL_MS, timeout=20_000
            )
            result = await page.text_content("tr.tune-edit[data-param=ATC_RAT_RLL_P] td.result")
            assert result == "", result
            assert await page.input_value(PARAM_BOX) == before
            assert abs(sim.params["ATC_RAT_RLL_P"] - float(before)) < 1e-4
            await browser.close()
    assert errors == [], errors
