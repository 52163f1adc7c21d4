"""The page's stream table shows the negotiation in headless Chromium (Debian's /usr/bin/chromium,
Playwright): simulator (`gcs sim --max-rate RAW_IMU=40`, its own process) → link → station →
uvicorn → page. RAW_IMU reads requested 50 → accepted 40 with the vehicle's refusal reason."""

from __future__ import annotations

import asyncio
import subprocess
import sys

from live import dashboard, launch_chromium, running_station, stop_process, wait_for
from playwright.async_api import async_playwright

REASON = "DENIED at 50 Hz: Requested rate for message ID 27 too fast. Increase SCHED_LOOP_RATE; accepted 40 Hz"


def test_stream_table_shows_accepted_rate_and_refusal_reason(udp_port):
    async def scenario():
        command = [sys.executable, "-m", "gcs", "sim", "--profile", "pixhawk", "--max-rate", "RAW_IMU=40"]
        sim = subprocess.Popen(
            [*command, "--link", f"udpout:127.0.0.1:{udp_port}"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        try:
            async with running_station(f"udpin:127.0.0.1:{udp_port}", estimate=False) as station:
                await wait_for(lambda: station.streams.requested, 60, "stream requests")
                async with dashboard(station, viser=False) as server, async_playwright() as pw:
                    browser = await launch_chromium(pw)
                    try:
                        page = await browser.new_page()
                        await page.goto(server.url)
                        row = page.locator("#streams tr", has_text="RAW_IMU").first
                        await row.wait_for(timeout=60_000)
                        await page.locator("#streams", has_text=REASON).wait_for(timeout=60_000)
                        return await row.inner_text(), await page.locator("#streams").inner_text()
                    finally:
                        await browser.close()
        finally:
            stop_process(sim)

    row, table = asyncio.run(scenario())
    assert row.split()[:4] == ["RAW_IMU", "50.0", "→", "40.0"], row
    assert REASON in table
