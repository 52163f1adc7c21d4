"""One responsive layout, on a 1366×768 laptop and a 390×844 phone, with live data in every panel:
no horizontal scroll, no element overlapping another (bounding boxes of every block of the page),
the 3-D view at least a quarter of the laptop's viewport, every chart above the laptop's fold (with
two reboots' notes above them too), and inside the 3-D view's frame (viser's own page) nothing drawn
over the scene on the phone (viser's bottom sheet and its software-WebGL notice hidden) nor over
the vehicle on the laptop (the minimized panel sits in a top corner), and viser's software-WebGL
notice nowhere (the page says it under the view); screenshots of both into test-artifacts/
(layout-laptop.png, layout-phone.png)."""

from __future__ import annotations

import asyncio
import time

import pytest
from conftest import free_port
from live import POLL_MS, dashboard, launch_chromium, open_dashboard, open_page, running_station, sim_process
from playwright.async_api import async_playwright

VIEWPORTS = {"laptop": (1366, 768), "phone": (390, 844)}
# The page's blocks: none may overlap another, none may reach past the viewport's width. A wide
# table scrolls sideways inside its own box (.scroll-x), never the page.
BLOCKS = [
    "header",
    "#plots > .toolbar",
    "#plots > .scroll-x",  # the two tables; a phone scrolls a wide one inside its box
    "#numbers-note",
    ".chart",
    "#pose",
    "#tabs",
    "#vehicle-state",
    "#autopilot-messages",
    "#track",
    "#streams",
    "#gains",
]

JS_LAYOUT = """(selectors) => {
  const boxes = [];
  for (const sel of selectors) for (const el of document.querySelectorAll(sel)) {
    const r = el.getBoundingClientRect();
    if (r.width && r.height) boxes.push({ sel, x: r.left + scrollX, y: r.top + scrollY, w: r.width, h: r.height,
                                          in_side: el.closest("aside") !== null });
  }
  const overlaps = [];
  for (let i = 0; i < boxes.length; i++) for (let j = i + 1; j < boxes.length; j++) {
    const a = boxes[i], b = boxes[j];
    const ix = Math.min(a.x + a.w, b.x + b.w) - Math.max(a.x, b.x);
    const iy = Math.min(a.y + a.h, b.y + b.h) - Math.max(a.y, b.y);
    if (ix > 1 && iy > 1) overlaps.push([a.sel, b.sel, Math.round(ix), Math.round(iy)]);
  }
  const pose = document.getElementById("pose").getBoundingClientRect();
  const aside = document.querySelector("aside").getBoundingClientRect();
  const side = { left: aside.left + scrollX - 0.5, right: aside.right + scrollX + 0.5 };
  return { boxes: boxes.length, overlaps, scrollWidth: document.documentElement.scrollWidth, width: innerWidth,
           beyond: boxes.filter((b) => b.x < -1 || b.x + b.w > innerWidth + 1).map((b) => b.sel),
           past_side: boxes.filter((b) => b.in_side && (b.x < side.left || b.x + b.w > side.right))
             .map((b) => [b.sel, Math.round(b.x + b.w - side.right)]),
           charts_below_fold: [...document.querySelectorAll(".chart")]
             .filter((el) => el.getBoundingClientRect().bottom > innerHeight + 1).length,
           pose_fraction: (pose.width * pose.height) / (innerWidth * innerHeight) };
}"""


# Inside viser's frame: every element that paints something (text, a background, an icon) and is
# positioned over the 3-D canvas; `over_vehicle`: those reaching into the middle third of the
# view each way, where the vehicle is drawn.
JS_POSE_FRAME = """() => {
  const canvas = [...document.querySelectorAll("canvas")].sort((a, b) => b.width * b.height - a.width * a.height)[0];
  if (!canvas) return null;
  const c = canvas.getBoundingClientRect();
  const mid = { x0: c.left + c.width / 3, x1: c.right - c.width / 3,
                y0: c.top + c.height / 3, y1: c.bottom - c.height / 3 };
  const paints = (el, cs) => ["SVG", "svg", "IMG", "BUTTON", "INPUT"].includes(el.tagName)
    || !/rgba\\(0, 0, 0, 0\\)|transparent/.test(cs.backgroundColor)
    || [...el.childNodes].some((n) => n.nodeType === 3 && n.textContent.trim());
  const overlays = [];
  for (const el of document.querySelectorAll("body *")) {
    const shown = el.checkVisibility({ opacityProperty: true, visibilityProperty: true });
    if (el === canvas || el.contains(canvas) || !shown) continue;
    const cs = getComputedStyle(el), r = el.getBoundingClientRect();
    if (r.width < 2 || r.height < 2 || !paints(el, cs)) continue;
    if (r.right <= c.left || r.left >= c.right || r.bottom <= c.top || r.top >= c.bottom) continue;
    const hit = r.right > mid.x0 && r.left < mid.x1 && r.bottom > mid.y0 && r.top < mid.y1;
    const box = [r.left, r.top, r.width, r.height].map(Math.round);
    overlays.push({ tag: el.tagName, text: (el.innerText || "").slice(0, 40), box, hit });
  }
  return { canvas: [c.width, c.height].map(Math.round), overlays, over_vehicle: overlays.filter((o) => o.hit) };
}"""


@pytest.mark.timeout(900)  # under a minute on a quiet machine
def test_layout_laptop_and_phone(udp_port, artifacts_dir):
    report = asyncio.run(asyncio.wait_for(scenario(udp_port, artifacts_dir), 840))
    print(f"\nlayout figures: {report}")
    for name, r in report.items():
        assert r["scrollWidth"] <= r["width"], (name, r)
        assert r["overlaps"] == [], (name, r["overlaps"])
        assert r["beyond"] == [], (name, r["beyond"])
        assert r["past_side"] == [], (name, r["past_side"])  # the 3-D view's frame was 2 px wider than its column
        assert r["boxes"] >= len(BLOCKS) + 5, (name, r)  # six charts and every panel were measured
    assert report["laptop"]["pose_fraction"] >= 0.25, report["laptop"]
    assert report["laptop"]["charts_below_fold"] == 0, report["laptop"]  # roll, pitch and yaw in sight
    with_note = report["laptop"]["with_note"]  # ... with two lines more above them (they pushed the yaw row off)
    assert with_note["charts_below_fold"] == 0 and with_note["overlaps"] == [], with_note
    readout = report["laptop"]["readout"]  # the values under the cursor, in the chart's title
    assert readout.startswith("t ") and "onboard" in readout and "dcm" in readout and "°" in readout, readout
    for name, r in report.items():
        assert r["pose_frame"]["over_vehicle"] == [], (name, r["pose_frame"])
        # viser's software-WebGL notice covered the top third of the laptop's view on every load
        assert not [o for o in r["pose_frame"]["overlays"] if "WebGL" in o["text"]], (name, r["pose_frame"])
        # ... the page says it instead (headless Chromium draws WebGL with SwiftShader)
        assert "software WebGL" in r["pose_renderer"], (name, r["pose_renderer"])
    assert report["phone"]["pose_frame"]["overlays"] == [], report["phone"]["pose_frame"]


async def settled_pose_frame(pose, phone: bool, timeout: float = 120.0) -> dict:
    """JS_POSE_FRAME once viser's page has laid out and taken the station's style (its canvas
    sized, nothing over the vehicle, on the phone nothing over the scene), or as it is at the
    deadline: viser mounts its panels and the style in its own time after the canvas appears."""
    deadline = time.monotonic() + timeout
    while True:
        frame = await pose.evaluate(JS_POSE_FRAME)
        clear = frame is not None and frame["canvas"] != [300, 150] and not frame["over_vehicle"]
        clear = clear and not [o for o in frame["overlays"] if "WebGL" in o["text"]]  # the notice, until hidden
        if (clear and not (phone and frame["overlays"])) or time.monotonic() > deadline:
            return frame
        await pose.wait_for_timeout(250)  # each look walks every element of the frame


async def scenario(udp_port: int, artifacts_dir) -> dict:
    report = {}
    errors: list[str] = []
    async with (
        running_station(f"udpin:127.0.0.1:{udp_port}") as station,
        sim_process(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad"),
    ):
        async with dashboard(station, viser_port=free_port()) as server, async_playwright() as pw:
            browser = await launch_chromium(pw)
            for name, (width, height) in VIEWPORTS.items():
                page = await open_page(browser, errors, width, height)
                await open_dashboard(
                    page,
                    server.url,
                    "document.querySelectorAll('#numbers-table tr[data-estimator]').length >= 6",
                    "(document.querySelector('#vehicle-GPS') || {}).textContent?.includes('satellites')",
                    "window.gcsPlots && gcsStats.historyLoads >= 2 && gcsPlots.draws > 0",
                )
                # a few more draws with live data, then the page's blocks are where they stay
                await page.wait_for_function(
                    "(n) => gcsPlots.draws >= n", arg=await page.evaluate("gcsPlots.draws") + 5, polling=POLL_MS
                )
                report[name] = await page.evaluate(JS_LAYOUT, BLOCKS)
                if name == "laptop":  # lines above the plots, as two reboots' notes: the charts make room
                    for from_s in (120.0, 45.0):
                        await page.evaluate(f"showRestart({{at: new Date(), from: {from_s}, to: 0.5}})")
                    await page.wait_for_function(
                        "(n) => gcsPlots.draws >= n", arg=await page.evaluate("gcsPlots.draws") + 3, polling=POLL_MS
                    )
                    report[name]["with_note"] = await page.evaluate(JS_LAYOUT, BLOCKS)
                over = await page.query_selector(".chart .u-over")
                assert over is not None
                await over.hover()
                await page.wait_for_function(
                    "document.querySelector('.chart .readout').textContent.includes('onboard')",
                    polling=POLL_MS,
                    timeout=60_000,
                )
                report[name]["readout"] = await page.eval_on_selector(".chart .readout", "el => el.textContent")
                await page.mouse.move(0, 0)
                # in sight, as when someone looks at it: Chromium does not lay out a frame off screen
                await page.locator("#pose").scroll_into_view_if_needed()
                pose = await (await page.wait_for_selector("#pose")).content_frame()
                assert pose is not None
                await pose.wait_for_selector("canvas", timeout=120_000)
                report[name]["pose_frame"] = await settled_pose_frame(pose, phone=name == "phone")
                report[name]["pose_renderer"] = await page.eval_on_selector("#pose-renderer", "el => el.textContent")
                await page.screenshot(path=str(artifacts_dir / f"layout-{name}.png"))
                await page.screenshot(path=str(artifacts_dir / f"layout-{name}-full.png"), full_page=True)
                await page.close()
            await browser.close()
    assert errors == [], errors
    return report
