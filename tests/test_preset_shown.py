"""A reset to a preset, made on one page, is named on every page. Two Chromium pages of one
station (the simulator in its own process over UDP, the real server): the engineer's page, with the
token, resets dcm to `seed000`; a teammate's page watches. Before, both pages went on heading dcm's
gains "(preset ardupilot)" while dcm ran seed000's gains (kp_rp 27.8), until each was reloaded;
only the gain values followed."""

from __future__ import annotations

import asyncio

import pytest
from live import POLL_MS, dashboard, launch_chromium, open_page, running_station, sim_process
from playwright.async_api import async_playwright

HEADING = "document.querySelector('#gains details summary').textContent"


@pytest.mark.timeout(240)
def test_a_reset_to_a_preset_is_named_on_every_page(udp_port):
    errors: list[str] = []

    async def scenario():
        async with (
            running_station(f"udpin:127.0.0.1:{udp_port}") as station,
            sim_process(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad"),
            dashboard(station, viser=False) as server,
            async_playwright() as pw,
        ):
            browser = await launch_chromium(pw)
            engineer, teammate = await open_page(browser, errors), await open_page(browser, errors)
            await engineer.goto(server.url)  # with the token
            await teammate.goto(f"http://127.0.0.1:{server.port}/")
            for page in (engineer, teammate):
                first = f"{HEADING}.includes('(preset ardupilot)')"
                await page.wait_for_function(first, polling=POLL_MS, timeout=120_000)
                await page.wait_for_function("(gcsStats.received.dcm || 0) > 0", polling=POLL_MS, timeout=120_000)
            reset = engineer.locator("#gains details").first
            await reset.locator("select").select_option("seed000")
            await reset.locator("button").click()
            await wait_gain(engineer, teammate)
            assert station.estimator("dcm").preset == "seed000"
            return [await page.evaluate(HEADING) for page in (engineer, teammate)]

    headings = asyncio.run(scenario())
    assert not errors, errors
    assert all("(preset seed000)" in h for h in headings), headings


async def wait_gain(*pages) -> None:
    """Until the reset's gains reached each page (seed000's kp_rp), then its heading, to a deadline."""
    value = "Number(document.querySelector('input[type=number][data-gain=kp_rp]').value) === 27.8"
    for page in pages:
        await page.wait_for_function(value, polling=POLL_MS, timeout=30_000)
    for page in pages:  # sent with the gains: a page that has them has had as long for it
        await page.wait_for_function(f"{HEADING}.includes('(preset seed000)')", polling=POLL_MS, timeout=10_000)
