"""The page's "now" table shows the sources' attitudes now, not one that stopped long ago. The
ArduCopter SITL hop (shared .tlog), replayed through the real station, its dashboard server and
real Chromium: its ATTITUDE is `onboard-unready` for 0.3 s at 5.7-6.0 s (its EKF_STATUS_REPORT
said the attitude not good yet), then `onboard` to the end at 93.5 s. The onboard-unready column
kept its value from 6.0 s for the whole flight, read as a second attitude now."""

from __future__ import annotations

import asyncio

from conftest import LOGS
from live import POLL_MS, dashboard, launch_chromium, open_dashboard, open_page, running_station, wait_for
from playwright.async_api import async_playwright

from gcs.mavlink.sampling import UNREADY
from gcs.server.estimates_body import STALE_AFTER, estimates_of

#: the now table's column heads: every source it shows
HEADS = "[...document.querySelectorAll('#now-table th')].slice(1).map((th) => th.textContent)"


def test_a_source_that_stopped_leaves_the_now_table_and_reads_stale():
    async def scenario():
        errors: list[str] = []
        hop = str(LOGS / "arducopter-sitl-hop.tlog")
        async with (
            running_station(hop, speed=2.0) as station,
            dashboard(station, viser=False) as server,
            async_playwright() as pw,
        ):
            browser = await launch_chromium(pw)
            page = await open_page(browser, errors)
            await open_dashboard(page, server.url, f"{HEADS}.includes('onboard')")
            # onboard-unready stopped at 6.0 s, the flight goes on to 93.5 s: its column must go
            await page.wait_for_function(f"!{HEADS}.includes('{UNREADY}')", polling=POLL_MS, timeout=60_000)
            heads = await page.evaluate(HEADS)
            await wait_for(lambda: station.snapshot is not None, 10, "a snapshot")
            sources = estimates_of(station.snapshot).sources
            await browser.close()
            return heads, sources, errors

    heads, sources, errors = asyncio.run(scenario())
    print("now table:", heads, {name: (round(s.t, 1), s.stale) for name, s in sources.items()})
    assert {"onboard", "dcm", "kf", "ekf", "truth"} <= set(heads) and UNREADY not in heads, heads
    newest = max(s.t for s in sources.values())
    assert sources[UNREADY].stale and newest - sources[UNREADY].t > STALE_AFTER, sources[UNREADY]
    assert not any(s.stale for name, s in sources.items() if name != UNREADY), sources
    assert errors == []
