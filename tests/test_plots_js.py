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
        ([10.0, 30.0], [175.0, -175.0]),  # far apart
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
    assert apart == [[9, 31]]  # where [11, 29] left the steep line's end pixels drawn


#: A Plots of the page in a 700 px box; onboard's yaw, sampled at `rate` Hz, turns at 60°/s for
#: 10 s, through +180° at t = 0.5 s and every 6 s after; returns the yaw chart's canvas pixels that
#: a line drew, antialiased edges too (the grid's are faint: alpha under 64), from
#: a column before the last sample ahead of the t = 6.5 s wrap to one after it, between +120° and
#: -120°, where only a line across the wrap could draw any.
LINE_AT_WRAP = """async (rate) => {
  const box = document.createElement("div"); box.style.width = "700px"; document.body.appendChild(box);
  const plots = new Plots(box, ["dcm"]);
  const ts = [], zero = [], yaw = [];
  for (let i = 0; i <= 10 * rate; i++) {
    const t = i / rate; ts.push(t); zero.push(0); yaw.push(((150 + 60 * t + 180) % 360) - 180);
  }
  plots.add("onboard", [ts, zero, zero, yaw]);
  await new Promise((done) => { const wait = () => (plots.draws > 0 ? done() : requestAnimationFrame(wait)); wait(); });
  const u = plots.charts[2].u, ctx = u.ctx;
  const x0 = Math.floor(u.valToPos(6.5 - 1 / rate, "x", true)) - 1, x1 = Math.ceil(u.valToPos(6.5, "x", true)) + 1;
  const top = Math.round(u.valToPos(120, "y", true)), bottom = Math.round(u.valToPos(-120, "y", true));
  const pixels = ctx.getImageData(x0, top, x1 - x0 + 1, bottom - top).data;
  let drawn = 0;
  for (let i = 0; i < pixels.length; i += 4) {
    if (pixels[i + 3] > 64) drawn++;
  }
  return { line: drawn, draws: plots.draws };
}"""


#: (device pixels per CSS pixel, the source's rate in Hz): a plain screen and a HiDPI one (a line
#: 1 CSS pixel wide is 3 canvas pixels wide there); a source at 100 Hz (binned: two points a
#: column), at 20 Hz (points ~3 canvas pixels apart on the HiDPI screen) and at 4 Hz
CASES = ((1, 100), (1, 4), (3, 20), (3, 4))


def test_the_pages_yaw_chart_draws_no_bar_at_the_wrap():
    """The whole chart, as the page builds it (uPlot, the binning, the chart's options), in each of
    CASES: wrapGaps only runs where uPlot asks for gaps, which it does not for a series that spans
    its nulls. The yaw charts spanned them, so every wrap was drawn as a bar across the chart (seen
    on the dashboard after the unit test above passed); then a slow source's wrap kept a stub at
    each end, and on a HiDPI screen the line's own width still drew a thin bar."""
    assets = web_assets()
    uplot_js = (assets.uplot / "uPlot.iife.min.js").read_text()
    plots_js = (assets.page / "plots.js").read_text()

    async def scenario():
        async with async_playwright() as pw:
            browser = await launch_chromium(pw)
            try:
                seen = []
                for scale, rate in CASES:
                    page = await browser.new_page(viewport={"width": 1366, "height": 768}, device_scale_factor=scale)
                    await page.add_script_tag(content=uplot_js)
                    await page.add_script_tag(content='window.GCS_COLORS = {onboard: "#000000", dcm: "#d62728"};')
                    await page.add_script_tag(content=plots_js)
                    seen.append(await page.evaluate(LINE_AT_WRAP, rate))
                return seen
            finally:
                await browser.close()

    for case, seen in zip(CASES, asyncio.run(scenario()), strict=True):
        assert seen["draws"] > 0 and seen["line"] == 0, (case, seen)
