"""The page over the simulated 57600 radio in headless Chromium (Debian's /usr/bin/chromium,
Playwright): `gcs sim --radio 57600` (its own process) → link → station → uvicorn → page. The radio
table shows wanted, predicted, requested and achieved rates; the "Download onboard log" button
fetches the vehicle's latest log into the replay folder, byte-identical."""

from __future__ import annotations

import asyncio
import subprocess
import sys

from live import CHROMIUM, CHROMIUM_ARGS, running_station, stop_process, wait_for
from playwright.async_api import async_playwright

from gcs.server.dashboard import DashboardServer

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
                f"udpin:127.0.0.1:{udp_port}", estimate=False, record_dir=str(tmp_path / "rec")
            ) as station:
                await wait_for(lambda: station.radio.present, 60, "the radio's RADIO_STATUS")
                server = DashboardServer(station, port=0, viser=False)
                await server.start()
                try:
                    async with async_playwright() as pw:
                        browser = await pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
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
                    await server.stop()
        finally:
            stop_process(sim)

    cells, status = asyncio.run(scenario())
    name, wanted, predicted, requested, achieved = cells[0], *map(float, cells[1:5])
    assert name == "RAW_IMU" and wanted == 50.0 and 5 <= predicted < 50 and requested < 50 and achieved > 0, cells
    # the latest log: the flight being flown, closed by the listing
    assert "log 2 downloaded" in status and "Replay list" in status, status
    (downloaded,) = (tmp_path / "rec").glob("log2-*.bin")
    assert downloaded.read_bytes() == (tmp_path / "vehicle" / "00000002.BIN").read_bytes()
