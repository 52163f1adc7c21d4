"""The page over the simulated 57600 radio in headless Chromium (Debian's /usr/bin/chromium,
Playwright): `gcs sim --radio 57600` (its own process) → link → station → uvicorn → page. The radio
table shows wanted, predicted, requested and achieved rates; the "Download onboard log" button
fetches the vehicle's latest log into the replay folder, byte-identical."""

from __future__ import annotations

import asyncio
import socket
import subprocess
import sys
from collections import Counter
from urllib.parse import urlparse

from live import (
    dashboard,
    launch_chromium,
    open_page,
    running_sim,
    running_station,
    stop_process,
    wait_for,
)
from playwright.async_api import async_playwright

from gcs.mavlink.dialect import Encoder, mavlink

#: the radio table's RAW_IMU row shows an achieved rate (its fifth cell) above 0
RAW_IMU_ACHIEVED = """() => [...document.querySelectorAll('#radio tr')].some(
  r => r.innerText.startsWith('RAW_IMU') && parseFloat(r.innerText.split(/\\s+/)[4]) > 0)"""


def test_radio_table_and_log_download_button(udp_port, tmp_path):
    async def scenario():
        command = [sys.executable, "-m", "gcs", "sim", "--profile", "apm25", "--radio", "57600"]
        sim = subprocess.Popen(
            [
                *command,
                "--flight-log",
                "3",
                "--log-dir",
                str(tmp_path / "vehicle"),
                "--link",
                f"udpout:127.0.0.1:{udp_port}",
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            async with running_station(
                f"udpin:127.0.0.1:{udp_port}", estimate=False, sessions_dir=str(tmp_path / "rec"), record=True
            ) as station:
                await wait_for(lambda: station.radio.present, 60, "the radio's RADIO_STATUS")
                async with dashboard(station, viser=False) as server, async_playwright() as pw:
                    browser = await launch_chromium(pw)
                    try:
                        page = await browser.new_page()
                        await page.goto(server.url)
                        # the row appears with the request; RAW_IMU arrives through the radio after it
                        await page.wait_for_function(RAW_IMU_ACHIEVED, polling=250, timeout=120_000)
                        row = page.locator("#radio tr", has_text="RAW_IMU").first
                        cells = (await row.inner_text()).split()
                        await page.click("button[data-tab=sessions]")
                        await page.click("#onboard-log-btn")
                        status = page.locator("#onboard-log-status", has_text="downloaded")
                        await status.wait_for(timeout=120_000)
                        return cells, await status.inner_text()
                    finally:
                        await browser.close()
        finally:
            stop_process(sim)

    cells, status = asyncio.run(scenario())
    name, wanted, predicted, requested, achieved = cells[0], *map(float, cells[1:5])
    assert name == "RAW_IMU" and wanted == 50.0 and 5 <= predicted < 50 and requested < 50 and achieved > 0, cells
    # the latest log: the flight being flown, closed by the listing
    assert "log 2 downloaded" in status and "Replay list" in status, status
    (downloaded,) = (tmp_path / "rec").glob("log2-*.bin")
    assert downloaded.read_bytes() == (tmp_path / "vehicle" / "00000002.BIN").read_bytes()


def test_the_page_says_radio_status_was_ignored_and_polls_the_status_once(udp_port):
    """RADIO_STATUS from the vehicle's own component (no radio's): the radio section says how
    many were ignored instead of staying hidden. It draws from the status the dashboard polls:
    the page asks for /api/status once per /api/estimates (and the panels once at the start), where
    a poll of its own added one every 2 s."""

    async def scenario():
        async with (
            running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk") as sim,
            running_station(f"udpin:127.0.0.1:{udp_port}", estimate=False) as station,
        ):
            await wait_for(lambda: sim.stream_rates().get("RAW_IMU") == 50.0, 30, "RAW_IMU sent at 50 Hz")
            status = Encoder(1, 1).encode(mavlink.MAVLink_radio_status_message(200, 200, 0, 20, 20, 0, 0))
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
                for _ in range(3):
                    sender.sendto(status, ("127.0.0.1", udp_port))
            await wait_for(lambda: station.radio.snapshot().ignored_status == 3, 30, "3 RADIO_STATUS ignored")
            async with dashboard(station, viser=False) as server, async_playwright() as pw:
                browser = await launch_chromium(pw)
                try:
                    errors: list[str] = []
                    page = await open_page(browser, errors)
                    asked: Counter[str] = Counter()
                    page.on("request", lambda r: asked.update([urlparse(r.url).path]))
                    await page.goto(server.url)
                    await page.locator("#radio", has_text="3 RADIO_STATUS").wait_for(timeout=60_000)
                    await wait_for(lambda: asked["/api/estimates"] >= 8, 60, "8 polls of the page")
                    return await page.locator("#radio").inner_text(), dict(asked), errors
                finally:
                    await browser.close()

    text, asked, errors = asyncio.run(scenario())
    assert "no radio: 3 RADIO_STATUS" in text and "ignored" in text, text
    # + 1 for the panels' request at the start, + 1 for a poll's status counted before its estimates
    # (a poll of the radio's own every 2 s would add 4 or more by the 8th)
    assert asked["/api/status"] <= asked["/api/estimates"] + 2, asked
    assert not errors, errors
