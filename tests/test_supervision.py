"""A station part that raises is seen within 2 s in /api/status, the event log (and the session's
events.jsonl) and on the page, while the other parts keep running."""

from __future__ import annotations

import asyncio
import json
import time

import httpx
from live import CHROMIUM, CHROMIUM_ARGS, POLL_MS, running_station, sim_process, wait_for
from playwright.async_api import async_playwright

from gcs.server.dashboard import DashboardServer
from gcs.sessions import layout


def test_failed_part_is_reported_and_the_rest_keeps_running(udp_port, tmp_path):
    report = asyncio.run(asyncio.wait_for(scenario(udp_port, tmp_path), 240))
    assert report["status_delay_s"] < 2.0, report
    assert report["page_delay_s"] < 2.0, report


async def scenario(udp_port: int, root) -> dict:
    report: dict = {}
    async with (
        running_station(f"udpin:127.0.0.1:{udp_port}", sessions_dir=str(root), record=True) as station,
        sim_process(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad", speed=2.0),
    ):
        server = DashboardServer(station, port=0, viser=False)
        await server.start()
        try:
            async with async_playwright() as pw, httpx.AsyncClient(base_url=f"http://127.0.0.1:{server.port}") as api:
                browser = await pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
                page = await browser.new_page()
                await page.goto(server.url)
                pipeline = station.estimation.pipeline
                await wait_for(lambda: pipeline.imu_samples > 100, 60, "IMU samples")
                # the page is up and polling the status before the fault
                await page.wait_for_function(
                    "document.querySelector('#link-state').textContent === 'link connected'",
                    polling=POLL_MS,
                    timeout=30_000,
                )

                def broken(item):
                    raise RuntimeError("injected fault in the estimation")

                pipeline.feed = broken  # the next input makes the estimation part raise
                failed_at = time.monotonic()
                failed_wall_ms = time.time() * 1000
                deadline = failed_at + 10
                while True:
                    parts = {p["name"]: p for p in (await api.get("/api/status")).json()["parts"]}
                    if parts["estimation"]["state"] == "failed":
                        break
                    assert time.monotonic() < deadline, parts
                    await asyncio.sleep(0.05)
                report["status_delay_s"] = time.monotonic() - failed_at
                assert "injected fault" in parts["estimation"]["error"]
                assert {p["state"] for name, p in parts.items() if name != "estimation"} == {"running"}

                # The page notes (on the machine's wall clock, shared with this process) when it
                # first shows the warning, so Playwright's round trips, slow on a loaded machine,
                # are not counted: what is timed is the page's own status poll and drawing.
                await page.wait_for_function(
                    "document.querySelector('#warnings').textContent.includes('station part estimation failed')"
                    " && (window.gcsSeenAt = Date.now())",
                    polling=POLL_MS,
                    timeout=30_000,
                )
                report["page_delay_s"] = (await page.evaluate("window.gcsSeenAt") - failed_wall_ms) / 1000
                await browser.close()

                events = [e for e in station.events.recent if e.kind == "part"]
                assert events and events[0].data["part"] == "estimation"
                # The rest keeps running: packets arrive, the recording grows, the API answers.
                packets, written = station.link.stats.framing.packets, station.recorder.snapshot().bytes_written
                await wait_for(
                    lambda: (
                        station.link.stats.framing.packets > packets + 100
                        and station.recorder.snapshot().bytes_written > written
                    ),
                    10,
                    "link and recorder after the failure",
                )
                assert (await api.get("/api/estimates")).status_code == 200
                folder = station.recorder.session.folder
        finally:
            await server.stop()
    lines = [json.loads(line) for line in (folder / layout.EVENTS).read_text().splitlines()]
    assert any(e["kind"] == "part" and e["part"] == "estimation" for e in lines)
    return report
