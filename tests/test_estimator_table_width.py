"""Every header of the dashboard's estimator tables is fully visible on a 1366×768 laptop, in real
Chromium with the classic scrollbars a desktop browser draws, against the station and the simulator
over UDP with live data (every estimator's lag known, the widest the live table gets). The audit
found the numbers table's "health" header clipped there: the table was wider than its column and
scrolled sideways inside its box, the header past the box's edge. And each estimator's lag,
searched against onboard ATTITUDE only, shows in its onboard row alone: shown in every row,
"dcm − truth" read as dcm that far behind (or ahead of) the truth."""

from __future__ import annotations

import asyncio

from live import POLL_MS, dashboard, launch_chromium, open_page, running_station, sim_process
from playwright.async_api import async_playwright

TABLES = ("#numbers-table", "#streams table")

# Each header's overflow inside itself, and how far its right edge reaches past the visible
# (client) area of the box it scrolls in and of the page.
JS_HEADERS = """(tables) => {
  const page = document.documentElement.clientWidth;
  const out = [];
  for (const sel of tables) for (const th of document.querySelectorAll(`${sel} th`)) {
    const box = th.closest(".scroll-x") || th.closest("section");
    const b = box.getBoundingClientRect(), r = th.getBoundingClientRect();
    const visible = b.left + box.clientLeft + box.clientWidth;
    out.push({ table: sel, text: th.textContent, overflow: th.scrollWidth - th.clientWidth,
               past_box: Math.round(r.right - visible), past_page: Math.round(r.right - page),
               box_scrolls: box.scrollWidth - box.clientWidth });
  }
  return { page, innerWidth, headers: out };
}"""

# each row's lag cell, by estimator|reference
JS_LAGS = """() => Object.fromEntries([...document.querySelectorAll('#numbers-table tr[data-estimator]')]
  .map((r) => [`${r.dataset.estimator}|${r.dataset.reference}`, r.cells[5].textContent]))"""

LAGS_KNOWN = """[...document.querySelectorAll('#numbers-table tr[data-estimator]')]
  .filter((tr) => / ms$/.test(tr.cells[5].textContent)).length >= 3
  && document.querySelectorAll('#streams th').length >= 6"""


def test_estimator_table_headers_fully_visible_at_1366(udp_port):
    report = asyncio.run(scenario(udp_port))
    print(f"\nheaders at 1366 px: {report}")
    assert report["page"] < report["innerWidth"], "no vertical scrollbar: the laptop's narrower page is not tested"
    headers = report["headers"]
    assert {h["text"] for h in headers} >= {"health", "lag", "IMU rate", "estimator"}, headers
    clipped = [h for h in headers if h["overflow"] > 0 or h["past_box"] > 0 or h["past_page"] > 0]
    assert clipped == [], f"headers not fully visible (px overflowing, past their box, past the page): {clipped}"
    scrolling = {h["table"] for h in headers if h["box_scrolls"] > 0}
    assert scrolling == set(), f"tables scrolling sideways at 1366 px: {scrolling}"
    lags = report["lags"]
    assert all(lags[f"{est}|truth"] == "–" for est in ("dcm", "kf", "ekf")), lags
    assert all(lags[f"{est}|onboard"].endswith(" ms") for est in ("dcm", "kf", "ekf")), lags


async def scenario(udp_port: int) -> dict:
    errors: list[str] = []
    async with (
        running_station(f"udpin:127.0.0.1:{udp_port}") as station,
        sim_process(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad"),
        dashboard(station, viser=False) as server,
        async_playwright() as pw,
    ):
        browser = await launch_chromium(pw, scrollbars=True)
        try:
            page = await open_page(browser, errors, 1366, 768)
            await page.goto(server.url, wait_until="commit")
            await page.wait_for_function(LAGS_KNOWN, polling=POLL_MS, timeout=180_000)
            report = await page.evaluate(JS_HEADERS, list(TABLES))
            report["lags"] = await page.evaluate(JS_LAGS)
        finally:
            await browser.close()
    assert errors == [], errors
    return report
