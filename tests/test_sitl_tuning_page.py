"""The dashboard's Tuning tab against the real ArduCopter SITL (../shared/sitl), in Debian's
Chromium driven by Playwright: what the engineer does with the keyboard reaches the vehicle, and
what the page then says is what the vehicle holds (read back from it, not from the page)."""

from __future__ import annotations

import asyncio
import os
import signal

import pytest
from live import (
    PANELS_READY,
    POLL_MS,
    dashboard,
    launch_chromium,
    open_dashboard,
    open_page,
    running_station,
    served_api,
    wait_for,
)
from playwright.async_api import TimeoutError as PlaywrightTimeout
from playwright.async_api import async_playwright
from test_sitl_copter import PROCESSES, sitl  # noqa: F401  (the fixture)

pytestmark = pytest.mark.slow

ROW = "tr.tune-edit[data-param=ATC_RAT_RLL_P]"
CURRENT = "#tuning-table tr.tune[data-param=ATC_RAT_RLL_P] td.cur"


def test_keyboard_arrows_on_a_slider_reach_the_vehicle(sitl):  # noqa: F811
    asyncio.run(asyncio.wait_for(keyboard_scenario(sitl), 240))


async def keyboard_scenario(port: int) -> None:
    """Six presses of → on a focused slider (each a step of 1/20 of the largest change per write)
    leave the vehicle at the sixth position, with no write refused. Each press was a write of its
    own: the first verified, the next five refused as rate-limited (0.2 s between writes of one
    parameter), the vehicle kept the first and the slider jumped back to it."""
    errors: list[str] = []
    async with (
        running_station(f"tcp:127.0.0.1:{port}") as station,
        dashboard(station, viser=False) as server,
        async_playwright() as pw,
    ):
        await wait_for(lambda: station.link.target_system is not None, 60, "SITL's heartbeat")
        start = (await station.params.read("ATC_RAT_RLL_P")).value
        browser = await launch_chromium(pw)
        page = await open_page(browser, errors, 1500, 1000)
        puts: list[int] = []
        page.on("response", lambda r: r.request.method == "PUT" and puts.append(r.status))
        await open_dashboard(page, server.url, PANELS_READY)
        await page.click("#tabs button[data-tab=tuning]")
        await page.locator("#param-download-btn").click(timeout=30_000)
        await page.wait_for_function(
            f"(document.querySelector('{CURRENT}')?.textContent || '–') !== '–'", polling=POLL_MS, timeout=120_000
        )
        slider = page.locator(f"{ROW} input[type=range]")
        step = await slider.evaluate("el => Number(el.step)")  # 1/20 of the largest change per write
        await slider.focus()
        wanted = start
        # six presses, then twenty: the second batch goes past the slider's first window (the
        # largest step either side of the value before the first write), which it kept while
        # focused: the vehicle stopped at start + 20 steps, the arrows did nothing more
        for presses in (6, 20):
            for _ in range(presses):
                await page.keyboard.press("ArrowRight")
            wanted = round(wanted + presses * step, 6)
            assert await slider.evaluate("el => Number(el.value)") == pytest.approx(wanted)
            try:
                await page.wait_for_function(
                    f"Math.abs(Number(document.querySelector('{CURRENT}').textContent) - {wanted}) < 1e-6"
                    f" && document.querySelector('{ROW} td.result').className === 'result verified'"
                    f" && Math.abs(Number(document.querySelector('{ROW} input[type=range]').max)"
                    f" - {wanted + 20 * step}) < 1e-6",
                    polling=POLL_MS,
                    timeout=30_000,
                )
            except PlaywrightTimeout:
                shown = await page.text_content(f"{ROW} td.result")
                window = await slider.evaluate("el => [Number(el.min), Number(el.max)]")
                raise AssertionError(f"wanted {wanted}, the slider spans {window}; the page says {shown!r}") from None
            assert (await station.params.read("ATC_RAT_RLL_P")).value == pytest.approx(wanted, abs=1e-6)
            assert puts and set(puts) == {200}, puts  # none refused as rate-limited (429)
            assert await slider.evaluate("el => Number(el.value)") == pytest.approx(wanted)
            assert "verified" in await page.text_content("#tuning-message")
        await browser.close()
    assert errors == [], errors


def test_a_write_while_the_link_is_lost_is_refused_at_once(sitl):  # noqa: F811
    asyncio.run(asyncio.wait_for(lost_link_scenario(sitl), 240))


async def lost_link_scenario(port: int) -> None:
    """SITL stopped (SIGSTOP: the link lost, the vehicle's socket kept): a gain write and "Revert
    all" are refused at once, saying why, and nothing reaches the vehicle when it is back. The
    write waited up to 10 s for a heartbeat and was made whenever the link came back, seconds
    after the click; the revert waited 10 s per changed parameter, then failed with a 504."""
    async with running_station(f"tcp:127.0.0.1:{port}") as station, served_api(station) as api:
        await wait_for(lambda: station.link.target_system is not None, 60, "SITL's heartbeat")
        assert (await api.post("/api/params/download")).status_code == 202
        await wait_for(lambda: station.params.complete, 120, "the parameter table")
        tuning = (await api.get("/api/tuning")).json()
        start = {p["name"]: p["current"] for p in tuning["params"]}
        changed = {name: round(start[name] + 0.01, 4) for name in ("ATC_RAT_RLL_P", "ATC_RAT_PIT_P")}
        for name, value in changed.items():  # two changes for the revert
            assert (await api.put(f"/api/tuning/{name}", json={"value": value})).status_code == 200
        pid = PROCESSES[port].pid
        os.kill(pid, signal.SIGSTOP)
        try:
            await wait_for(lambda: station.link.state == "lost", 30, "the link lost")
            value = {"value": round(changed["ATC_RAT_RLL_P"] + 0.01, 4)}
            write = asyncio.create_task(api.put("/api/tuning/ATC_RAT_RLL_P", json=value, timeout=60))
            await wait_for(write.done, 5, "the write's answer while the link is lost")
            revert = asyncio.create_task(api.post("/api/tuning/revert", timeout=60))
            await wait_for(revert.done, 5, "the revert's answer while the link is lost")
        finally:
            os.kill(pid, signal.SIGCONT)
        answer = write.result()
        assert answer.status_code == 422, answer.text
        assert (
            answer.json()["detail"]
            == "ATC_RAT_RLL_P: not written: the link to the vehicle is lost; try again when it is back"
        )
        answer = revert.result()
        assert answer.status_code == 422, answer.text
        assert (
            answer.json()["detail"]
            == "not reverted, nothing written: the link to the vehicle is lost; try again when it is back"
        )
        await wait_for(lambda: station.link.state == "connected", 30, "the link back")
        for name, value in changed.items():
            assert (await station.params.read(name)).value == pytest.approx(value)
