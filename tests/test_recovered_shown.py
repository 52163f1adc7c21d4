"""A session a crash left open is closed at the next start and the dashboard's Sessions tab says so
by name. `gcs serve` killed with -9 while recording the simulator (each a process of its own), a new
station on the same folder, the page in Chromium: before, the recording line read "recovered after
a crash: [object Object]" (the page joined the recovery reports, objects, as text)."""

from __future__ import annotations

import asyncio
import signal
import subprocess
import sys

import pytest
from conftest import ROOT, free_port
from live import POLL_MS, dashboard, launch_chromium, open_page, running_station, sim_process, stop_process, wait_for
from playwright.async_api import async_playwright

from gcs.sessions import layout


@pytest.mark.timeout(300)
def test_the_sessions_tab_names_the_session_a_crash_left_open(tmp_path, udp_port):
    root = tmp_path / "sessions"

    async def crash() -> None:
        command = [sys.executable, "-m", "gcs", "serve", "--connect", f"udpin:127.0.0.1:{udp_port}"]
        command += ["--port", str(free_port()), "--record-dir", str(root)]
        serve = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            async with sim_process(f"udpout:127.0.0.1:{udp_port}"):

                def recording() -> bool:  # a session folder with some attitude in it
                    folders = [p for p in root.iterdir() if layout.is_session(p)] if root.exists() else []
                    return any(layout.stream_path(p, "attitude").exists() for p in folders)

                await wait_for(recording, 120, "the session being recorded", poll=0.2)
                serve.send_signal(signal.SIGKILL)
                serve.wait(10)
        finally:
            stop_process(serve)

    async def restart() -> str:
        errors: list[str] = []
        async with (
            running_station(f"udpin:127.0.0.1:{free_port()}", sessions_dir=str(root), record=True) as station,
            dashboard(station, viser=False) as server,
            async_playwright() as pw,
        ):
            browser = await launch_chromium(pw)
            page = await open_page(browser, errors)
            await page.goto(server.url)
            await page.get_by_text("Sessions", exact=True).first.click()
            await page.wait_for_function(
                "document.getElementById('rec-status').textContent.includes('recovered after a crash')",
                polling=POLL_MS,
                timeout=60_000,
            )
            assert not errors, errors
            return await page.evaluate("document.getElementById('rec-status').textContent")

    asyncio.run(crash())
    (folder,) = [p for p in root.iterdir() if layout.is_session(p)]
    assert layout.read_meta(folder)["end"] is None  # left open by the kill
    shown = asyncio.run(restart())
    assert f"recovered after a crash: {folder.name}" in shown, shown
    assert "[object Object]" not in shown, shown
