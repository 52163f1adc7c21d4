"""Helpers for tests (and bench.page_fps) that run the real simulator against the real link over
real sockets, and the dashboard in real Chromium."""

from __future__ import annotations

import asyncio
import contextlib
import os
import subprocess
import sys
import time

from gcs.runtime.station import Station, StationConfig
from gcs.sim import SimVehicle

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",  # software WebGL for the 3-D view
    "--disable-gpu-compositing",  # compositing in software without the GPU process: rAF at 60 Hz, not 2-30
    # Page tiles and the plots' 2-D canvases drawn by Skia on the CPU, not through SwiftShader's GL
    # emulation in the GPU process (which Playwright turns on, and which then took most of a core
    # on a loaded 2-core machine, starving the page and the station); only WebGL uses SwiftShader.
    "--disable-gpu-rasterization",
    "--disable-accelerated-2d-canvas",
    "--no-sandbox",
    "--host-resolver-rules=MAP * ~NOTFOUND , EXCLUDE 127.0.0.1",  # not even DNS lookups leave the machine
]
# Page-side waits poll on a timer, not on animation frames (Playwright's default): what they wait
# for is data, which must not depend on how fast the page manages to draw.
POLL_MS = 20


async def launch_chromium(playwright, scrollbars: bool = False):
    """Debian's Chromium (never a downloaded one). A missing browser fails the test (CI must have
    it), it never skips it. `scrollbars`: classic scrollbars, as a desktop browser draws them (a
    vertical one takes 15 px of a 1366 px window); Playwright's headless default hides them."""
    if not os.path.exists(CHROMIUM):
        raise AssertionError(f"{CHROMIUM} missing: run bash .ci/setup")
    ignore = ["--hide-scrollbars"] if scrollbars else None  # None: all of Playwright's default arguments
    return await playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, ignore_default_args=ignore)


async def open_page(browser, errors: list[str], width: int = 1366, height: int = 768):
    """A page of that size whose console errors and uncaught exceptions land in `errors`."""
    page = await browser.new_page(viewport={"width": width, "height": height})
    page.on("console", lambda m: m.type == "error" and errors.append(m.text))
    page.on("pageerror", lambda e: errors.append(str(e)))
    return page


#: The page's tab buttons have their handlers (panels.js ran): a tab clicked before that stays
#: closed, and on a loaded machine a test sometimes clicked first.
PANELS_READY = "window.gcsPanels !== undefined"


async def open_dashboard(page, url: str, *ready: str) -> None:
    """Load the dashboard at `url` and wait until each of the page-side conditions `ready` holds
    (a first start may still be compiling the estimators: minutes, on a loaded machine)."""
    await page.goto(url, timeout=300_000, wait_until="commit")
    for condition in ready:
        await page.wait_for_function(condition, polling=POLL_MS, timeout=300_000)


@contextlib.asynccontextmanager
async def dashboard(station: Station, **kwargs):
    """The station's DashboardServer on a free port (kwargs: viser, viser_port, hub, ...)."""
    from gcs.server.dashboard import DashboardServer

    server = DashboardServer(station, port=0, **kwargs)
    await server.start()
    try:
        yield server
    finally:
        await server.stop()


@contextlib.asynccontextmanager
async def running_sim(address: str, profile: str = "apm25", **kwargs):
    sim = SimVehicle(profile=profile, **kwargs)
    task = asyncio.create_task(sim.run(address))
    try:
        yield sim
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)


@contextlib.asynccontextmanager
async def sim_process(address: str, profile: str = "pixhawk", script: str = "quad", speed: float = 1.0):
    """The simulator as `gcs sim` in a process of its own. Scenarios with a browser use it: the
    test's event loop then carries only the station, the server and Playwright, and a loaded
    machine slows the page, never the vehicle's clock (one loop for all of them fell behind for
    good at load 8-12 on two cores)."""
    command = [sys.executable, "-m", "gcs", "sim", "--profile", profile, "--script", script]
    proc = subprocess.Popen(
        [*command, "--speed", str(speed), "--link", address], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        yield proc
    finally:
        stop_process(proc)


def stop_process(proc: subprocess.Popen, timeout: float = 10.0) -> None:
    """SIGTERM, then SIGKILL after `timeout` s: a test never leaves its child running."""
    proc.terminate()
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


@contextlib.asynccontextmanager
async def running_station(connect: str, **kwargs):
    station = Station(StationConfig(connect=connect, **kwargs))
    await station.start()
    try:
        yield station
    finally:
        await station.stop()


@contextlib.asynccontextmanager
async def served_api(station: Station):
    """The station's dashboard server on a free port and an authorised HTTP client to it."""
    import httpx

    async with (
        dashboard(station, viser=False) as server,
        httpx.AsyncClient(base_url=f"http://127.0.0.1:{server.port}", headers=server.auth_headers) as api,
    ):
        yield api


async def wait_for(predicate, timeout: float, what: str, poll: float = 0.05) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        await asyncio.sleep(poll)


async def resend_until(condition, what: str, resend, timeout: float = 90.0, every: float = 0.5) -> None:
    """Send (`resend()`) until `condition()` holds, again every `every` s: a command a vehicle may
    drop or refuse while it is busy (a mode change, arming), to a deadline."""
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        resend()
        await asyncio.sleep(every)


@contextlib.contextmanager
def other_system(port: int, answer, sysid: int = 200):
    """Another system on a station's udpin `port` (a second ground station, a companion, a hostile
    peer): a thread that sends GCS heartbeats as `sysid`, so the station sends it what it sends
    the vehicle, and answers each of those messages with `answer(msg, mav)`'s messages at once.
    Yields the messages it answered."""
    import socket
    import threading

    from gcs.mavlink.dialect import mavlink

    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.settimeout(0.05)
    stop = threading.Event()
    answered: list = []
    mav, parser = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=1), mavlink.MAVLink(None)

    def run() -> None:
        heartbeat = mav.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 4).pack(mav)
        while not stop.is_set():
            peer.sendto(heartbeat, ("127.0.0.1", port))
            try:
                data = peer.recv(65535)
            except TimeoutError:
                continue
            for msg in parser.parse_buffer(data) or []:
                replies = answer(msg, mav)
                for reply in replies:
                    peer.sendto(reply.pack(mav), ("127.0.0.1", port))
                if replies:
                    answered.append(msg)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        yield answered
    finally:
        stop.set()
        thread.join()
        peer.close()
