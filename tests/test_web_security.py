"""Another web page the engineer has open cannot change anything: a page served from a second
origin on loopback, in real Chromium, tries every state-changing endpoint (fetch with text/plain
and no-cors, with and without credentials; form posts) and the live WebSocket, while the engineer's own tab
holds the token cookie. Nothing changes, and each attempt is refused and logged with its origin."""

from __future__ import annotations

import asyncio
import importlib
import json
import os

import pytest
from fastapi.routing import APIRoute
from live import CHROMIUM, CHROMIUM_ARGS, running_station, sim_process, wait_for
from playwright.async_api import async_playwright

from gcs.server.dashboard import DashboardServer
from gcs.server.deps import TOKEN_HEADER
from gcs.server.routers import ROUTERS

ATTACK = """<!doctype html><html><body><iframe name="sink"></iframe><script>
const targets = %s;
window.done = (async () => {
  for (const [method, url] of targets) {
    for (const credentials of ["include", "omit"]) {
      for (const mode of ["no-cors", "cors"]) {
        try {
          await fetch(url, {method, mode, credentials, headers: {"content-type": "text/plain"},
                            body: method === "GET" ? undefined : '{"value": 1.5, "text": "x", "source": "x"}'});
        } catch (e) {}
      }
    }
    if (method === "POST") {
      const form = document.createElement("form");
      form.method = "POST"; form.action = url; form.target = "sink"; form.enctype = "text/plain";
      const field = document.createElement("input"); field.name = '{"value": 1.5, "x": "'; field.value = '"}';
      form.appendChild(field); document.body.appendChild(form); form.submit();
      await new Promise(r => setTimeout(r, 50));
    }
  }
  window.socket = await new Promise(resolve => {
    const ws = new WebSocket(%s);
    ws.onopen = () => resolve("open"); ws.onerror = () => resolve("refused"); ws.onclose = () => resolve("refused");
  });
  return true;
})();
</script></body></html>"""


def state_changing() -> list[tuple[str, str]]:
    """(method, path) of every route that changes state, path parameters filled in."""
    out = []
    routes = [r for module in ROUTERS for r in importlib.import_module(module).router.routes]
    for route in routes:
        if isinstance(route, APIRoute):
            for method in route.methods - {"GET", "HEAD"}:
                path = (
                    route.path.replace("{name}", "dcm").replace("{gain}", "kp_rp").replace("{param}", "ATC_RAT_RLL_P")
                )
                out.append((method, path))
    return sorted(set(out))


def test_a_page_of_another_origin_changes_nothing(udp_port, tmp_path, attacker_site):
    if not os.path.exists(CHROMIUM):
        pytest.fail(f"{CHROMIUM} missing: run bash .ci/setup")
    site_dir, site = attacker_site
    asyncio.run(scenario(udp_port, tmp_path / "sessions", site_dir, site))


async def scenario(udp_port: int, record_dir, site_dir, site: str) -> None:
    async with (
        running_station(f"udpin:127.0.0.1:{udp_port}", sessions_dir=str(record_dir), record=True) as station,
        sim_process(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad"),
    ):
        server = DashboardServer(station, port=0, viser=False)
        await server.start()
        try:
            await wait_for(lambda: station.estimation.pipeline.imu_samples > 50, 30, "IMU samples")
            base = f"http://127.0.0.1:{server.port}"
            targets = [(method, base + path) for method, path in state_changing()]
            assert len(targets) >= 10  # replay changes nothing on the server any more: it is a GET
            (site_dir / "attack.html").write_text(
                ATTACK % (json.dumps(targets), json.dumps(f"ws://127.0.0.1:{server.port}/ws/live"))
            )
            gains = {n: dict(e.gains.values) for n, e in station.estimation.pipeline.estimators.items()}
            recording = station.recorder.snapshot().state
            async with async_playwright() as pw:
                browser = await pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
                context = await browser.new_context()
                # The engineer's own tab holds the token cookie; the attacker's page, same site (another
                # loopback port, which SameSite does not tell apart), sends it along with credentials.
                dashboard = await context.new_page()
                await dashboard.goto(server.url)
                assert (await dashboard.evaluate("fetch('/api/status').then((r) => r.json())"))["authorised"]
                assert any(c["name"] == f"gcs_token_{server.port}" for c in await context.cookies())
                page = await context.new_page()
                await page.goto(f"{site}/attack.html")
                assert await page.evaluate("window.done") is True
                assert await page.evaluate("window.socket") == "refused"
                await browser.close()
            assert {n: dict(e.gains.values) for n, e in station.estimation.pipeline.estimators.items()} == gains
            assert station.recorder.snapshot().state == recording == "recording"
            assert not server.hub.clients
            assert not [e for e in station.events.recent if e.kind in ("gain", "note", "param")]
            refused = [e for e in station.events.recent if e.kind == "refused"]
            assert {e.data["origin"] for e in refused} == {site}
            assert {e.data["path"] for e in refused} >= {path for _, path in state_changing()} | {"/ws/live"}
        finally:
            await server.stop()


def test_a_50_mb_body_is_refused_at_once(udp_port):
    """The guard answers 413 from the headers: the server never waits for, or holds, the 50 MB."""

    async def scenario() -> None:
        async with running_station(f"udpin:127.0.0.1:{udp_port}") as station:
            server = DashboardServer(station, port=0, viser=False)
            await server.start()
            try:
                for framing in (b"Content-Length: 52428800\r\n", b"Transfer-Encoding: chunked\r\n"):
                    reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
                    writer.write(
                        b"PUT /api/estimators/dcm/gains/kp_rp HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                        + framing
                        + f"Content-Type: application/json\r\n{TOKEN_HEADER}: {server.token}\r\n\r\n".encode()
                    )
                    chunk = b"x" * 65536 if b"Length" in framing else b"10000\r\n" + b"x" * 65536 + b"\r\n"
                    writer.write(chunk + chunk)  # 128 KiB past the limit, of the 50 MB announced or to come
                    await writer.drain()
                    status = await asyncio.wait_for(reader.readline(), 30)
                    assert status.startswith(b"HTTP/1.1 413"), (framing, status)
                    writer.close()
                assert station.estimation.pipeline.estimators["dcm"].gains["kp_rp"] == 0.2
            finally:
                await server.stop()

    asyncio.run(scenario())


#: Requests another loopback origin's page makes without any script reading the answer: an image,
#: a credentialed no-cors fetch, and a link opened in a new window. Same site as the dashboard
#: (another port), so the browser sends the engineer's SameSite=Strict cookie with them, and no
#: Origin header (a GET).
SUBRESOURCES = """<!doctype html><html><body><a id="open" href="%s" target="_blank">tuning</a><script>
window.done = (async () => {
  for (const url of %s) {
    await new Promise(r => { const img = new Image(); img.onload = img.onerror = r; img.src = url; });
    try { await fetch(url, {mode: "no-cors", credentials: "include"}); } catch (e) {}
  }
  return true;
})();
</script></body></html>"""


def test_a_page_of_another_origin_neither_opens_tuning_nor_spends_the_engineers_budget(tmp_path, attacker_site):
    """GET /api/tuning with the token opens the tuning session (it reads the profile's parameters
    from the vehicle); the export and the replay cost seconds of the worker, and each client
    address may ask for only so many a minute. Another page on loopback sends the cookie along
    and shares the engineer's address: it must get none of them."""
    site_dir, site = attacker_site
    asyncio.run(subresource_scenario(tmp_path / "sessions", site_dir, site))


async def subresource_scenario(record_dir, site_dir, site: str) -> None:
    from test_params_protocol import station_and_sim

    async with station_and_sim("apm25", estimate=True) as (station, _sim):
        server = DashboardServer(station, port=0, viser=False)
        await server.start()
        try:
            await station.params.download(timeout=60)
            base = f"http://127.0.0.1:{server.port}"
            costly = [f"{base}/api/replay?source=none", f"{base}/api/sessions/none/export"] * 10
            attack = SUBRESOURCES % (f"{base}/api/tuning", json.dumps([f"{base}/api/tuning", *costly]))
            (site_dir / "attack.html").write_text(attack)
            async with async_playwright() as pw:
                browser = await pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
                context = await browser.new_context()
                dashboard = await context.new_page()
                await dashboard.goto(server.url)
                page = await context.new_page()
                await page.goto(f"{site}/attack.html")
                assert await page.evaluate("window.done") is True
                async with context.expect_page() as opened:
                    await page.click("#open")  # the engineer clicks a link on that page
                popup = await opened.value
                await popup.wait_for_load_state()
                assert "not opened yet" in await popup.content()  # the page opens, read-only
                assert station.started_tuning() is None  # the cookie opened it
                # the engineer's own budget is whole: a 404 for no such source, not a 429
                own = "(u) => fetch(u).then((r) => r.status)"
                assert await dashboard.evaluate(own, f"{base}/api/replay?source=none") == 404
                assert await dashboard.evaluate(own, f"{base}/api/sessions/none/export") == 404
                await browser.close()
            refused = [e for e in station.events.recent if e.kind == "refused"]
            assert {e.data["reason"] for e in refused} == {"site"}
            assert {e.data["path"] for e in refused} == {"/api/tuning", "/api/replay", "/api/sessions/none/export"}
        finally:
            await server.stop()
