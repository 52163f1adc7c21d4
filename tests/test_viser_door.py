"""viser's port has the dashboard's front door (gcs.server.viser_door): another web page cannot
open its socket (which streams the attitudes and gains), a foreign Host (DNS rebinding) gets
nothing, and a client's message is read up to 64 KiB, where viser read 50 MB and decoded it at
once (2 MB of empty msgpack arrays: 140 MB more RSS, kept)."""

from __future__ import annotations

import asyncio
import http.client
import json
import struct

import viser
from conftest import free_port
from live import launch_chromium, running_station, wait_for
from playwright.async_api import async_playwright
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from gcs.server.dashboard import DashboardServer
from gcs.server.scene import LocalViserServer

SUBPROTOCOL = f"viser-v{viser.__version__}"

ATTACK = """<!doctype html><html><body><script>
window.socket = new Promise(resolve => {
  const ws = new WebSocket(%s, [%s]);
  ws.binaryType = "arraybuffer";
  ws.onmessage = () => { resolve("read the scene"); ws.close(); };
  ws.onerror = ws.onclose = () => resolve("refused");
});
</script></body></html>"""


def test_another_page_cannot_open_the_3d_views_socket(udp_port, attacker_site):
    site_dir, site = attacker_site

    async def scenario() -> None:
        async with running_station(f"udpin:127.0.0.1:{udp_port}") as station:
            server = DashboardServer(station, port=0)
            await server.start()
            try:
                view = f"ws://127.0.0.1:{server.viser_port}"
                (site_dir / "attack.html").write_text(ATTACK % (json.dumps(view), json.dumps(SUBPROTOCOL)))
                async with async_playwright() as pw:
                    browser = await launch_chromium(pw)
                    page = await browser.new_page()
                    await page.goto(f"{site}/attack.html")
                    assert await page.evaluate("window.socket") == "refused"
                    # the dashboard's own frame of the view still opens and reads it
                    dashboard = await browser.new_page()
                    await dashboard.goto(f"http://127.0.0.1:{server.port}/")
                    frame = dashboard.frame_locator("iframe").first
                    await frame.locator("canvas").first.wait_for(timeout=120_000)
                    await browser.close()
                await wait_for(lambda: refused(station), 10, "the refusal in the event log")
                (event,) = refused(station)
                assert event.data["origin"] == site and event.data["reason"] == "origin"
            finally:
                await server.stop()

    asyncio.run(scenario())


def refused(station) -> list:
    return [e for e in station.events.recent if e.kind == "refused"]


def test_a_foreign_host_gets_nothing_from_the_3d_views_port():
    port = free_port()
    server = LocalViserServer("127.0.0.1", port)
    try:
        for host, status in (("evil.example", 403), (f"127.0.0.1:{port}", 200)):
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
            conn.request("GET", "/", headers={"Host": host})
            answer = conn.getresponse()
            assert answer.status == status, (host, answer.status)
            if status == 403:
                assert b"DNS rebinding" in answer.read()
            conn.close()
    finally:
        server.stop()


def test_a_client_message_is_read_up_to_64_kib():
    """A 2 MB GuiUpdateMessage whose value is an array of empty arrays: each byte a Python list."""
    n = 2_000_000
    body = (
        b"\x83\xa4type\xb0GuiUpdateMessage\xa4uuid\xa1x\xa7updates\x81\xa5value\xdd"
        + struct.pack(">I", n)
        + b"\x90" * n
    )
    port = free_port()
    server = LocalViserServer("127.0.0.1", port)
    try:
        before = rss_mb()
        with connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], max_size=None) as ws:
            ws.send(body)
            code = None
            try:
                while True:
                    ws.recv(timeout=10)
            except ConnectionClosed as exc:
                code = exc.rcvd.code if exc.rcvd else None
            except TimeoutError:
                pass
        assert code == 1009, f"viser read the 2 MB message (close code {code})"
        assert rss_mb() - before < 40
    finally:
        server.stop()


def rss_mb() -> float:
    with open("/proc/self/status") as status:
        line = next(line for line in status if line.startswith("VmRSS"))
    return int(line.split()[1]) / 1024
