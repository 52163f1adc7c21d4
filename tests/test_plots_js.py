"""The page's plot code (web/public/plots.js) in headless Chromium (Debian's, Playwright), on its
own: where a yaw line wraps at ±180° no line is drawn, however close the points are."""

from __future__ import annotations

import asyncio

from live import launch_chromium
from playwright.async_api import async_playwright

from gcs.server.assets import web_assets

#: a chart with x in canvas pixels; each case: the points' x and yaw, and where the wrap lies
WRAP_GAPS = """(cases) => cases.map(([xs, ys]) => {
  const u = { data: [xs, ys], valToPos: (x) => x };
  return wrapGaps(u, 1, 0, xs.length - 1, []);
})"""


def test_a_yaw_wrap_is_never_drawn_as_a_bar():
    """Two points in one pixel column (the min and max of the samples there, at +0.25 and +0.75
    of it), neighbouring columns, and points far apart: the gap covers the wrap in every case
    (where the points were a pixel or two apart it was empty, [b + 1, a - 1], and the line went
    from +179° to -179° across the chart)."""
    plots_js = (web_assets().page / "plots.js").read_text()
    cases = [
        ([10.25, 10.75, 11.25, 11.75], [179.0, -179.0, -178.0, -177.0]),  # within a column
        ([10.25, 10.75, 11.25, 11.75], [170.0, 179.0, -179.0, -170.0]),  # between neighbouring columns
        ([10.0, 30.0], [175.0, -175.0]),  # far apart: the points themselves stay drawn
    ]

    async def scenario():
        async with async_playwright() as pw:
            browser = await launch_chromium(pw)
            try:
                page = await browser.new_page()
                await page.add_script_tag(content=plots_js)
                return await page.evaluate(WRAP_GAPS, cases)
            finally:
                await browser.close()

    within, between, apart = asyncio.run(scenario())
    assert len(within) == 1 and within[0][0] <= 10.25 and within[0][1] >= 10.75, within
    assert len(between) == 1 and between[0][0] <= 10.75 and between[0][1] >= 11.25, between
    assert apart == [[11, 29]]
