"""Redraw rate of the live dashboard in headless Chromium (Debian's /usr/bin/chromium), laptop
layout (1366×768): the simulated vehicle (`gcs sim`, its own process) → station → uvicorn → page.
`python -m bench.page_fps [--seconds S] [--no-viser]`

Baseline, measured in the same run on the same page: the browser's animation frames per second
(requestAnimationFrame callbacks, the most the page could draw). Reported: the plots' redraws per
second against it, the main-thread JavaScript time of one redraw (six uPlot charts: binning and
setData), the live data frames the page received per second (it redraws only when new samples
came: more redraws would show nothing new), the frames the 3-D view rendered per second
(three.js's own count in viser's frame),
and where the CPU went meanwhile (CPU % of a core per Chromium process type, of the station and
of the simulator): what limits the rate when the page's own work does not.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys
import time

import psutil
from playwright.async_api import async_playwright

from gcs.transport.address import free_port
from tests.live import dashboard, launch_chromium, running_station, sim_process

# Counts animation frames and times every chart draw, on the page's own clock.
PROBE = """() => {
  window.gcsBench = { raf: 0, drawMs: 0, draws0: gcsPlots.draws, frames0: gcsStats.messages, t0: performance.now() };
  const tick = () => { gcsBench.raf++; requestAnimationFrame(tick); }; requestAnimationFrame(tick);
  for (const c of gcsPlots.charts) {
    const draw = c.draw.bind(c);
    c.draw = (...a) => { const s = performance.now(); draw(...a); gcsBench.drawMs += performance.now() - s; };
  }
}"""
RESULT = """() => {
  const s = (performance.now() - gcsBench.t0) / 1000, draws = gcsPlots.draws - gcsBench.draws0;
  return { raf_per_s: gcsBench.raf / s, draws_per_s: draws / s, draw_ms: draws ? gcsBench.drawMs / draws : null,
           frames_per_s: (gcsStats.messages - gcsBench.frames0) / s };
}"""
# Frames three.js rendered in viser's page so far (viser exposes its renderer's info for tests).
VISER_FRAMES = "() => window.__viserTestpoints ? __viserTestpoints.rendererInfo.render.frame : null"
READY = "window.gcsPlots && gcsStats.historyLoads >= 2 && gcsStats.messages > 50"


def chromium_processes(browser_pid: int) -> dict[int, str]:
    """Chromium's processes by pid: their --type (renderer, gpu-process, utility, ...) or browser."""
    found = {}
    for proc in [psutil.Process(browser_pid), *psutil.Process(browser_pid).children(recursive=True)]:
        with_type = [a for a in proc.cmdline() if a.startswith("--type=")]
        found[proc.pid] = with_type[0][7:] if with_type else "browser"
    return found


def cpu_seconds(pids: list[int]) -> dict[int, float]:
    out = {}
    for pid in pids:
        try:
            t = psutil.Process(pid).cpu_times()
            out[pid] = t.user + t.system
        except psutil.NoSuchProcess:
            pass
    return out


async def measure(seconds: float, viser: bool) -> dict:
    port = free_port()
    address = f"127.0.0.1:{port}"
    async with (
        running_station(f"udpin:{address}") as station,
        sim_process(f"udpout:{address}", profile="pixhawk", script="quad") as sim,
        dashboard(station, viser=viser) as server,
        async_playwright() as pw,
    ):
        browser = await launch_chromium(pw)
        page = await browser.new_page(viewport={"width": 1366, "height": 768})
        await page.goto(server.url, timeout=300_000, wait_until="commit")
        await page.wait_for_function(READY, timeout=300_000)
        await page.wait_for_timeout(3000)
        pose = await (await page.query_selector("#pose")).content_frame() if viser else None
        chromium_pid = next(  # under Playwright's driver: the Chromium whose parent is not one
            p.pid
            for p in psutil.Process().children(recursive=True)
            if p.name().startswith("chrom") and not p.parent().name().startswith("chrom")
        )
        kinds = chromium_processes(chromium_pid)
        pids = [*kinds, os.getpid(), sim.pid]
        names = {**kinds, os.getpid(): "station + server (this process)", sim.pid: "simulator"}
        cpu0, wall0 = cpu_seconds(pids), time.monotonic()
        frames0 = await pose.evaluate(VISER_FRAMES) if pose else None
        await page.evaluate(PROBE)
        await page.wait_for_timeout(seconds * 1000)
        result = await page.evaluate(RESULT)
        frames1 = await pose.evaluate(VISER_FRAMES) if pose else None
        cpu1, wall = cpu_seconds(pids), time.monotonic() - wall0
        await browser.close()
    cpu: dict[str, list[float]] = {}
    for pid in cpu1:
        cpu.setdefault(names[pid], []).append(round(100 * (cpu1[pid] - cpu0.get(pid, 0.0)) / wall, 1))
    result["cpu_percent"] = {k: sorted(v, reverse=True) for k, v in cpu.items()}
    result["viser_frames_per_s"] = round((frames1 - frames0) / wall, 1) if frames0 is not None else None
    result["load_avg_1m"] = round(os.getloadavg()[0], 2)
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
                "data_frames_per_s": round(r["frames_per_s"], 1),
                "viser_frames_per_s": r["viser_frames_per_s"],
                "cpu_percent": r["cpu_percent"],
                "load_avg_1m": r["load_avg_1m"],
            }
        )
    return rows


if __name__ == "__main__":
    for row in main(sys.argv[1:]):
        print(row)
