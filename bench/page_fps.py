"""Redraw rate of the live dashboard in headless Chromium (Debian's /usr/bin/chromium), laptop
layout (1366×768): the simulated vehicle (`gcs sim`, its own process) → station → uvicorn → page.
`python -m bench.page_fps [--seconds S] [--no-viser]`

Baseline, measured in the same run on the same page: the browser's animation frames per second
(requestAnimationFrame callbacks, the most the page could draw). Reported: the plots' redraws per
second against it, the main-thread JavaScript time of one redraw (six uPlot charts: binning and
setData), and the share of the main thread the page's own work took (the plots yield two thirds of
it by design, see plots.js `frame`), which is what limits the rate once one redraw exceeds 16.7 ms.
"""

from __future__ import annotations

import argparse
import asyncio
import socket
import subprocess
import sys

from playwright.async_api import async_playwright

from gcs.runtime.station import Station, StationConfig
from gcs.server.dashboard import DashboardServer

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [  # as tests/test_browser.py: software WebGL and compositing, CPU raster
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-gpu-compositing",
    "--disable-gpu-rasterization",
    "--disable-accelerated-2d-canvas",
    "--no-sandbox",
    "--host-resolver-rules=MAP * ~NOTFOUND , EXCLUDE 127.0.0.1",
]

# Counts animation frames and times every chart draw, on the page's own clock.
PROBE = """() => {
  window.gcsBench = { raf: 0, drawMs: 0, draws0: gcsPlots.draws, t0: performance.now() };
  const tick = () => { gcsBench.raf++; requestAnimationFrame(tick); }; requestAnimationFrame(tick);
  for (const c of gcsPlots.charts) {
    const draw = c.draw.bind(c);
    c.draw = (...a) => { const s = performance.now(); draw(...a); gcsBench.drawMs += performance.now() - s; };
  }
}"""
RESULT = """() => {
  const s = (performance.now() - gcsBench.t0) / 1000, draws = gcsPlots.draws - gcsBench.draws0;
  return { raf_per_s: gcsBench.raf / s, draws_per_s: draws / s, draw_ms: draws ? gcsBench.drawMs / draws : null };
}"""
SIM = [sys.executable, "-m", "gcs", "sim", "--profile", "pixhawk", "--script", "quad"]
READY = "window.gcsPlots && gcsStats.historyLoads >= 2 && gcsStats.messages > 50"


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


async def measure(seconds: float, viser: bool) -> dict:
    port = free_udp_port()
    station = Station(StationConfig(connect=f"udpin:127.0.0.1:{port}"))
    await station.start()
    sim = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "gcs",
            "sim",
            "--profile",
            "pixhawk",
            "--script",
            "quad",
            "--link",
            f"udpout:127.0.0.1:{port}",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    server = DashboardServer(station, port=0, viser=viser)
    await server.start()
    try:
        async with async_playwright() as pw:
            browser = await pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            page = await browser.new_page(viewport={"width": 1366, "height": 768})
            await page.goto(server.url, timeout=300_000, wait_until="commit")
            await page.wait_for_function(
                "window.gcsPlots && gcsStats.historyLoads >= 2 && gcsStats.messages > 50", timeout=300_000
            )
            await page.wait_for_timeout(3000)
            await page.evaluate(PROBE)
            await page.wait_for_timeout(seconds * 1000)
            result = await page.evaluate(RESULT)
            await browser.close()
    finally:
        await server.stop()
        sim.terminate()
        sim.wait(10)
        await station.stop()
    return result


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=15.0)
    parser.add_argument("--no-viser", action="store_true", help="without the 3-D view's iframe")
    args = parser.parse_args(argv or [])
    rows = []
    for viser in (False,) if args.no_viser else (True, False):
        r = asyncio.run(measure(args.seconds, viser))
        draw_ms = r["draw_ms"]
        rows.append(
            {
                "benchmark": f"dashboard redraws/s, 1366x768, {'with' if viser else 'without'} the 3-D view",
                "value": round(r["draws_per_s"], 1),
                "baseline": f"{r['raf_per_s']:.1f} animation frames/s",
                "ratio": round(r["draws_per_s"] / r["raf_per_s"], 2) if r["raf_per_s"] else None,
                "note": f"one redraw {draw_ms:.1f} ms of JS (6 charts)" if draw_ms else "no redraw",
            }
        )
    return rows


if __name__ == "__main__":
    for row in main(sys.argv[1:]):
        print(row)
