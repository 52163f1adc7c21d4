"""The vehicle's state and the numbers at a glance, end to end: the simulator (its own process)
→ link → station → uvicorn → Chromium. The vehicle panel shows the simulator's mode, armed state,
battery and the STATUSTEXT it sent when armed (also recorded in the event log); the comparison
table shows the same RMS as /api/estimates to the displayed precision."""

from __future__ import annotations

import asyncio
import time

import pytest
from live import POLL_MS, dashboard, launch_chromium, open_page, running_station, sim_process, wait_for
from playwright.async_api import async_playwright

from gcs.mavlink.dialect import mavlink


@pytest.mark.timeout(900)  # under a minute on a quiet machine
def test_vehicle_panel_and_numbers(udp_port, artifacts_dir):
    asyncio.run(asyncio.wait_for(scenario(udp_port, artifacts_dir), 840))


def shown(x: float | None) -> str:
    """A number as the table shows it: two decimals, "–" when unknown."""
    return "–" if x is None else f"{x:.2f}"


def text_has(selector: str, text: str) -> str:
    return f"(document.querySelector({selector!r}) || {{}}).textContent?.includes({text!r})"


async def shows(page, selector: str, text: str, timeout: float = 120_000) -> None:
    await page.wait_for_function(text_has(selector, text), polling=POLL_MS, timeout=timeout)


async def scenario(udp_port: int, artifacts_dir) -> None:
    errors: list[str] = []
    async with running_station(f"udpin:127.0.0.1:{udp_port}") as station:
        async with dashboard(station, viser=False) as server, async_playwright() as pw:
            browser = await launch_chromium(pw)
            page = await open_page(browser, errors)
            async with sim_process(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad"):
                await wait_for(lambda: station.link.target_system is not None, 120, "the vehicle's heartbeat")
                await page.goto(server.url, timeout=300_000, wait_until="commit")
                # what the simulator sends: ArduCopter STABILIZE (custom_mode 0), disarmed, 12.40 V, 80 %
                await page.wait_for_function(text_has("#vehicle-mode", "STABILIZE"), polling=POLL_MS, timeout=300_000)
                await page.wait_for_function(text_has("#vehicle-battery", "12.40 V"), polling=POLL_MS, timeout=120_000)
                assert "80 %" in await page.text_content("#vehicle-battery")
                assert await page.text_content("#vehicle-armed") == "disarmed"
                await page.wait_for_function(
                    text_has("#vehicle-GPS", "12 satellites"), polling=POLL_MS, timeout=120_000
                )
                assert "3D FIX" in await page.text_content("#vehicle-GPS") and "HDOP 0.90" in await page.text_content(
                    "#vehicle-GPS"
                )
                await page.wait_for_function(text_has("#vehicle-EKF", "ATTITUDE"), polling=POLL_MS, timeout=120_000)

                # Arm it, as a ground station does: the simulator says "Arming motors".
                station.link.send(
                    mavlink.MAVLink_command_long_message(
                        station.link.target_system,
                        station.link.target_component,
                        mavlink.MAV_CMD_COMPONENT_ARM_DISARM,
                        0,
                        1,
                        0,
                        0,
                        0,
                        0,
                        0,
                        0,
                    )
                )
                await page.wait_for_function(
                    text_has("#autopilot-messages", "Arming motors"), polling=POLL_MS, timeout=120_000
                )
                await page.wait_for_function(text_has("#vehicle-armed", "ARMED"), polling=POLL_MS, timeout=120_000)
                assert "INFO" in await page.text_content("#autopilot-messages li")
                recorded = [e for e in station.events.recent if e.kind == "statustext"]
                assert recorded and recorded[-1].data["text"] == "Arming motors", recorded
                await page.wait_for_function(
                    "document.querySelectorAll('#numbers-table tr[data-estimator]').length >= 6",
                    polling=POLL_MS,
                    timeout=120_000,
                )
                await page.locator("#vehicle").screenshot(path=str(artifacts_dir / "vehicle-panel.png"))
            # The vehicle has stopped: the numbers hold still, and once a station snapshot and a page
            # poll have followed the last sample the page's table equals the API's.
            table_js = """() => Object.fromEntries([...document.querySelectorAll('#numbers-table tr[data-estimator]')]
                .map((r) => [`${r.dataset.estimator}|${r.dataset.reference}`,
                             [r.querySelector('.rms-window').textContent,
                              r.querySelector('.rms-session').textContent]]))"""

            async def page_and_api():
                table = await page.evaluate(table_js)
                api = await page.evaluate("fetch('/api/estimates').then((r) => r.json())")
                expect = {
                    f"{est}|{ref}": [
                        " / ".join(shown(x) for x in api["sources"][est]["errors"][ref][k])
                        for k in ("window_rms_deg", "session_rms_deg")
                    ]
                    for est in ("dcm", "kf", "ekf")
                    for ref in ("onboard", "truth")
                }
                return {key: table.get(key) for key in expect}, expect

            deadline = time.monotonic() + 60
            shown_rows, expect = await page_and_api()
            while shown_rows != expect and time.monotonic() < deadline:
                await page.wait_for_timeout(POLL_MS)
                shown_rows, expect = await page_and_api()
            assert shown_rows == expect
            now = await page.text_content("#now-table")
            assert "onboard" in now and "ekf" in now
            await page.locator("#plots").screenshot(path=str(artifacts_dir / "numbers.png"))
            await browser.close()
    assert errors == [], errors
