"""The dashboard end to end in headless Chromium (Debian's /usr/bin/chromium, driven by
Playwright): simulator → link → estimation → server → page. No mocks: real sockets, real
uvicorn and viser, a real browser rendering with SwiftShader WebGL."""

from __future__ import annotations

import asyncio
import io
import time

import httpx
from conftest import free_port
from live import POLL_MS, dashboard, launch_chromium, open_page, running_station, sim_process, wait_for
from PIL import Image
from playwright.async_api import TimeoutError as PlaywrightTimeout
from playwright.async_api import async_playwright

# The page must hold the end of the measured window within this (it takes under a second when
# nothing is lost; a lost sample fails the count, not this wait).
CATCH_UP_DEADLINE_MS = 20_000
# The measured window: ATTITUDE messages the bus delivers (10 s of the 50 Hz stream on a quiet
# machine), a stretch of data however slowly a loaded machine runs; and the deadline for it.
ATTITUDE_WINDOW = 500
WINDOW_DEADLINE_S = 120


def test_dashboard_in_chromium(udp_port, artifacts_dir):
    # Its own deadline below pytest's: a page that stops answering (page.evaluate has no timeout)
    # fails here with the line it hung on, and the station, server and browser are still closed.
    report = asyncio.run(asyncio.wait_for(dashboard_scenario(udp_port, artifacts_dir), 240))
    print(f"\nbrowser figures: {report}")
    assert report["console_errors"] == [], report["console_errors"]
    assert report["attitude_delivery"] >= 0.95, report
    assert report["slider_latency_s"] < 2.0, report
    assert report["script_gain_shown_s"] < 10.0, report
    # a gain in rad reads as a person writes it: dcm's mag_dip_tol is 10° (0.17453292519943295 rad)
    meaning, value = report["dip_gain_row"]
    assert meaning.endswith("[0 … 3.142]") and value == "0.174533", report["dip_gain_row"]
    assert report["pose_view_colours"] > 20, report
    # the lag's sign is explained on the page without hovering, and the declination's source shown
    assert "lag +20 ms = estimator 20 ms behind onboard" in report["status_note"], report["status_note"]
    assert "from vehicle COMPASS_DEC" in report["status_note"], report["status_note"]


async def dashboard_scenario(udp_port: int, artifacts_dir) -> dict:
    report: dict = {"console_errors": []}
    async with (
        running_station(f"udpin:127.0.0.1:{udp_port}") as station,
        sim_process(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad"),
        dashboard(station, viser_port=free_port()) as server,
        async_playwright() as pw,
    ):
        browser = await launch_chromium(pw)
        page = await open_page(browser, report["console_errors"], 1500, 1000)
        await page.goto(server.url)
        await page.wait_for_function(
            "window.gcsStats && (gcsStats.received.onboard || 0) > 20", polling=POLL_MS, timeout=30_000
        )
        await page.wait_for_function(
            "document.querySelector('#streams').innerText.includes('vehicle COMPASS_DEC')",
            polling=POLL_MS,
            timeout=30_000,
        )
        report["status_note"] = await page.inner_text("#streams .note")
        report.update(await attitude_delivery(station, page))
        report["server_feed"] = [c.snapshot() for c in server.hub.clients.values()]
        report["slider_latency_s"] = await slider_latency(page)
        report["script_gain_shown_s"] = await script_gain_shown(server, page)
        report["dip_gain_row"] = await page.evaluate(JS_DIP_GAIN_ROW)
        report["fps"] = await page.evaluate("gcsStats.fps")
        report["pose_view_colours"] = await pose_view_colours(page)
        await page.screenshot(path=str(artifacts_dir / "dashboard.png"))
        await browser.close()
    return report


async def attitude_delivery(station, page, count: int = ATTITUDE_WINDOW) -> dict:
    """Share of a window of `count` ATTITUDE messages the bus delivered that the page holds
    as onboard samples (matched on vehicle time), counted once the page holds a sample at or past
    the window's end: frames arrive in order, so whatever of the window is missing then was lost,
    not late. `catch_up_s`: how long after the window the page got there."""
    sub = station.bus.subscribe("test-attitude", types=["ATTITUDE"], maxlen=100_000)
    await wait_for(lambda: sub.delivered >= count, WINDOW_DEADLINE_S, f"{count} ATTITUDE messages")
    times = [m.vehicle_time for m in sub.drain()]
    sub.close()
    t0, t1 = min(times), max(times)
    start = time.monotonic()
    try:
        await page.wait_for_function(
            f"gcsPlots.sources.onboard.last() >= {t1 - 1e-4}", polling=POLL_MS, timeout=CATCH_UP_DEADLINE_MS
        )
        catch_up = round(time.monotonic() - start, 3)
    except PlaywrightTimeout:
        catch_up = None  # never got there: the count below shows how much is missing
    received = await page.evaluate(f"gcsCount('onboard', {t0 - 1e-4}, {t1 + 1e-4})")
    return {"attitude_delivery": received / len(times), "attitude_sent": len(times), "catch_up_s": catch_up}


async def slider_latency(page) -> float:
    """Move the kf declination slider to 1 rad and time (on the page's clock) until the plotted
    kf − onboard yaw error exceeds 5°: a declination change turns the kf yaw smoothly through its
    heading correction (no jump), so the error grows over a few tenths of a second.
    The page notes the time when its poll first sees it, so Playwright's round trips (slow on a
    loaded machine) are not counted."""
    await page.evaluate("document.querySelector('#gains details:nth-of-type(2)').open = true")
    slider = page.locator('input[type=range][data-estimator="kf"][data-gain="declination"]')
    before = await yaw_error(page)
    assert abs(before) < 5, f"kf − onboard yaw error already {before:.1f}° before the change"
    await slider.evaluate(
        "el => { window.gcsMoved = performance.now(); el.value = 1.0; "
        "el.dispatchEvent(new Event('input', {bubbles: true})); }"
    )
    await page.wait_for_function(
        f"Math.abs({JS_YAW_ERROR}) > 5 && (window.gcsSeen = performance.now())", polling=POLL_MS, timeout=10_000
    )
    return await page.evaluate("(window.gcsSeen - window.gcsMoved) / 1000")


#: dcm's mag_dip_tol row: its meaning line (with the bounds) and its number box
JS_DIP_GAIN_ROW = """(() => {
  const row = document.querySelector('[data-estimator=dcm][data-gain=mag_dip_tol]').parentElement;
  return [row.querySelector('.meaning').textContent, row.querySelector('[type=number]').value];
})()"""


async def script_gain_shown(server, page) -> float:
    """A gain a script changes (REST, with the token) reaches the page's gain box: the event
    travels in the live stream as a JSON frame between the points (wire.js). Seconds to show it."""
    box = "document.querySelector('[data-estimator=dcm][data-gain=kp_rp]').parentElement.querySelector('[type=number]')"
    async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{server.port}", headers=server.auth_headers) as api:
        start = time.monotonic()
        answer = await api.put("/api/estimators/dcm/gains/kp_rp", json={"value": 0.3125})
        assert answer.status_code == 200, answer.text
    await page.wait_for_function(f"{box}.value === '0.3125'", polling=POLL_MS, timeout=10_000)
    return round(time.monotonic() - start, 3)


JS_YAW_ERROR = (
    "(() => { const s = gcsPlots.errors.find((x) => x.e === 'kf' && x.r === 'onboard').series; "
    "s.update(); return s.v[2].length ? s.v[2][s.v[2].length - 1] : 0; })()"
)


async def yaw_error(page) -> float:
    return await page.evaluate(JS_YAW_ERROR)


async def pose_view_colours(page) -> int:
    """Distinct colours in the viser iframe's WebGL canvas (a blank canvas has 1-2); viser's
    first cold start can come up without its scene, so reload the iframe once if needed."""
    colours = 0
    for attempt in range(2):
        frame = page.frame_locator("#pose")
        canvas = frame.locator("canvas").first
        try:
            await canvas.wait_for(timeout=15_000)
            deadline = time.monotonic() + 15  # the scene drawn: looked at until it shows, or the deadline
            while colours <= 20 and time.monotonic() < deadline:
                await asyncio.sleep(0.25)
                shot = await canvas.screenshot()
                colours = len(Image.open(io.BytesIO(shot)).convert("RGB").getcolors(maxcolors=1 << 24))
        except Exception as exc:
            print(f"pose view attempt {attempt}: {exc}")
        if colours > 20:
            break
        await page.evaluate("document.getElementById('pose').src += ''")
    return colours
