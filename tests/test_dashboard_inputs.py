"""The dashboard's number boxes and its word on the server, in headless Chromium (Debian's
/usr/bin/chromium, driven by Playwright) against the real server under uvicorn: an emptied box is
no value (not a write of 0), and a server that stops under an open page is said to be gone, in
red, and the page comes back when it is served again."""

from __future__ import annotations

import asyncio
import signal
import socket
import subprocess
import sys
import time

from conftest import free_port
from live import (
    PANELS_READY,
    POLL_MS,
    dashboard,
    launch_chromium,
    open_dashboard,
    open_page,
    running_sim,
    running_station,
    sim_process,
    stop_process,
    wait_for,
)
from playwright.async_api import TimeoutError as PlaywrightTimeout
from playwright.async_api import async_playwright

from gcs.server.dashboard import DashboardServer

# dcm's dip tolerance, [0 … 3.142] rad: 0 is a value it takes
GAIN_BOX = "#gains details:has(summary[data-estimator=dcm]) input[type=number][data-gain=mag_dip_tol]"
PARAM_BOX = "tr.tune-edit[data-param=ATC_RAT_RLL_P] input[type=number]"


async def empty_box(page, selector: str) -> None:
    """Clear a box and leave it (Tab), as a person does: the browser fires `change` with value ""."""
    box = page.locator(selector)
    await box.fill("")
    await box.press("Tab")


def test_emptied_boxes_write_nothing(udp_port):
    asyncio.run(asyncio.wait_for(emptied_boxes_scenario(udp_port), 240))


async def emptied_boxes_scenario(udp_port: int) -> None:
    errors: list[str] = []
    async with (
        running_station(f"udpin:127.0.0.1:{udp_port}") as station,
        running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad") as sim,
        dashboard(station, viser=False) as server,
    ):
        await wait_for(lambda: station.link.target_system is not None, 30, "the vehicle's heartbeat")
        async with async_playwright() as pw:
            browser = await launch_chromium(pw)
            page = await open_page(browser, errors)
            await open_dashboard(page, server.url, f"document.querySelector('{GAIN_BOX}') !== null")
            held = await page.input_value(GAIN_BOX)
            assert held == "0.174533", held
            await page.wait_for_function("(gcsStats.received.onboard || 0) > 100", polling=POLL_MS, timeout=60_000)
            await zoom_says_live(page)

            # A gain's box emptied: the gain is kept and the box shows it again (it was set to 0).
            await empty_box(page, GAIN_BOX)
            await page.wait_for_function(
                f"document.querySelector('{GAIN_BOX}').value !== ''", polling=POLL_MS, timeout=20_000
            )
            gains = await page.evaluate(
                "fetch('/api/estimators').then((r) => r.json()).then((es) =>"
                " es.find((e) => e.name === 'dcm').gains.find((g) => g.name === 'mag_dip_tol').value)"
            )
            assert abs(gains - 0.17453292519943295) < 1e-9, gains
            assert await page.input_value(GAIN_BOX) == held

            # A vehicle parameter's box emptied: no write is asked for (it was a write of 0).
            await page.click("#tabs button[data-tab=tuning]")
            download = page.locator("#param-download-btn")
            await download.wait_for(state="visible", timeout=30_000)
            await download.click()
            await page.wait_for_function(
                f"document.querySelector('{PARAM_BOX}') && document.querySelector('{PARAM_BOX}').value !== ''",
                polling=POLL_MS,
                timeout=30_000,
            )
            before = await page.input_value(PARAM_BOX)
            await empty_box(page, PARAM_BOX)
            await page.wait_for_function(
                f"document.querySelector('{PARAM_BOX}').value !== ''", polling=POLL_MS, timeout=20_000
            )
            result = await page.text_content("tr.tune-edit[data-param=ATC_RAT_RLL_P] td.result")
            assert result == "", result
            assert await page.input_value(PARAM_BOX) == before
            assert abs(sim.params["ATC_RAT_RLL_P"] - float(before)) < 1e-4
            await browser.close()
    assert errors == [], errors


def test_server_gone_and_back(udp_port):
    asyncio.run(asyncio.wait_for(server_gone_scenario(udp_port, same_token=True), 240))


def test_server_back_with_another_token(udp_port):
    """gcs serve restarted without --token makes a new token: the open page's cookie no longer
    allows changes, and its controls say so (they stayed enabled, each click refused with 401)."""
    asyncio.run(asyncio.wait_for(server_gone_scenario(udp_port, same_token=False), 240))


async def server_gone_scenario(udp_port: int, same_token: bool) -> None:
    errors: list[str] = []
    async with (
        running_station(f"udpin:127.0.0.1:{udp_port}") as station,
        sim_process(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad"),
        async_playwright() as pw,
    ):
        browser = await launch_chromium(pw)
        page = await open_page(browser, errors)
        connected = "document.querySelector('#link-state').className === 'pill connected'"
        async with dashboard(station, viser=False) as first:
            await open_dashboard(page, first.url, connected)
        await page.wait_for_function(
            "document.querySelector('#link-state').textContent === 'server unreachable'",
            polling=POLL_MS,
            timeout=20_000,
        )
        # not the green pill of a connected link, and the numbers are not read as live
        assert await page.get_attribute("#link-state", "class") == "pill lost"
        assert "no answer from the station's server" in await page.text_content("#warnings")

        # served again on the same port: the page says so without a reload
        server = DashboardServer(station, port=first.port, token=first.token if same_token else None, viser=False)
        await server.start()
        try:
            await page.wait_for_function(connected, polling=POLL_MS, timeout=30_000)
            assert "no answer" not in await page.text_content("#warnings")
            if same_token:
                assert not await page.is_disabled("#protocol-start")
            else:
                await page.wait_for_function(
                    "document.querySelector('#protocol-start').disabled", polling=POLL_MS, timeout=20_000
                )
                assert await page.is_disabled("#gains input[type=range] >> nth=0")
                await page.click("#tabs button[data-tab=protocol]")
                assert await page.locator("#tab-protocol .readonly-note").is_visible()
        finally:
            await server.stop()
        await browser.close()
    # Chromium's own lines for the requests made while nothing listened
    assert [e for e in errors if "ERR_CONNECTION_REFUSED" not in e] == [], errors


def test_read_only_page(udp_port):
    asyncio.run(asyncio.wait_for(read_only_scenario(udp_port), 240))


async def read_only_scenario(udp_port: int) -> None:
    """A page opened without the token: every control whose request needs it is disabled, the
    gains and the what-if as the tuning, recording and protocol controls."""
    errors: list[str] = []
    async with (
        running_station(f"udpin:127.0.0.1:{udp_port}") as station,
        dashboard(station, viser=False) as server,
        async_playwright() as pw,
    ):
        browser = await launch_chromium(pw)
        page = await open_page(browser, errors)
        await open_dashboard(
            page, f"http://127.0.0.1:{server.port}/", "document.querySelector('#gain-note').textContent !== ''"
        )
        enabled = await page.evaluate(
            "[...document.querySelectorAll('#gains input, #gains select, #gains button, #whatif-run')]"
            ".filter((el) => !el.disabled).map((el) => el.id || el.dataset.gain || el.textContent)"
        )
        assert enabled == [], enabled
        await page.click("#tabs button[data-tab=whatif]")
        assert await page.locator("#tab-whatif .readonly-note").is_visible()
        await browser.close()
    assert errors == [], errors


def test_hung_server(tcp_port):
    asyncio.run(asyncio.wait_for(hung_server_scenario(tcp_port), 240))


async def hung_server_scenario(port: int) -> None:
    """A server that stops answering without closing its sockets (gcs demo stopped with SIGSTOP:
    as a hung process, or a network that drops every packet): the page says it is unreachable
    within its 5 s status timeout, with one status request waiting at a time (and one of each
    panel's poll: recording, vehicle list, Protocol and Tuning tabs), and comes back when the
    server does. The old page waited for ever, a request more each second, showing its last
    answer as live."""
    import httpx

    errors: list[str] = []
    viser_port = free_port(socket.SOCK_STREAM)
    command = [sys.executable, "-m", "gcs", "demo", "--no-record", "--port", str(port), "--token", "t0k"]
    proc = subprocess.Popen(
        [*command, "--viser-port", str(viser_port)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        deadline = time.monotonic() + 120
        async with httpx.AsyncClient() as client:
            while True:
                try:
                    if (await client.get(f"http://127.0.0.1:{port}/api/status")).status_code == 200:
                        break
                except httpx.TransportError:
                    pass
                assert time.monotonic() < deadline and proc.poll() is None, "gcs demo never served"
                await asyncio.sleep(0.2)
        async with async_playwright() as pw:
            browser = await launch_chromium(pw)
            page = await open_page(browser, errors)
            connected = "document.querySelector('#link-state').className === 'pill connected'"
            await open_dashboard(page, f"http://127.0.0.1:{port}/?token=t0k", connected)
            # a page on each tab that polls a panel of its own: Protocol every 1 s, Tuning every 5 s
            # (its parameter table is not downloaded: each poll is one GET /api/params)
            tabs = {}
            for tab, ready in (("protocol", "#protocol-name"), ("tuning", "#param-progress-text")):
                tabs[tab] = await open_page(browser, errors)
                await open_dashboard(tabs[tab], f"http://127.0.0.1:{port}/", connected)
                await tabs[tab].click(f"#tabs button[data-tab={tab}]")
                await tabs[tab].wait_for_function(
                    f"document.querySelector('{ready}').textContent !== ''", polling=POLL_MS, timeout=30_000
                )
            polls: list[str] = []
            others: dict[str, int] = {"/api/recording": 0, "/api/vehicles": 0}
            panels: dict[str, int] = {"/api/protocol": 0, "/api/params": 0}

            def path_of(request) -> str:
                return request.url.split("?")[0].removeprefix(f"http://127.0.0.1:{port}")

            def count(request) -> None:
                path = path_of(request)
                if path == "/api/status":
                    polls.append(path)
                elif path in others:
                    others[path] += 1

            def count_panel(request) -> None:
                if path_of(request) in panels:
                    panels[path_of(request)] += 1

            page.on("request", count)
            proc.send_signal(signal.SIGSTOP)
            for tab in tabs.values():  # from the stop on: the one request each that then waits
                tab.on("request", count_panel)
            try:
                await page.wait_for_function(
                    "document.querySelector('#link-state').textContent === 'server unreachable'",
                    polling=POLL_MS,
                    timeout=20_000,
                )
                assert len(polls) <= 2, len(polls)  # the one waiting (and one before the stop, at most)
                assert "none in 5 s" in await page.text_content("#warnings")
                # 10 s and more without an answer: the 2-s polls of the recording and the vehicle
                # list have one request each waiting, not one more each time (5 each on the old page)
                await wait_for(lambda: len(polls) >= 3, 30, "a third status poll, 5 s after the second")
                assert max(others.values()) <= 2, others
                # 15 s and more: the Protocol and Tuning tabs' polls too (about 15 and 3 on the old page)
                await wait_for(lambda: len(polls) >= 4, 30, "a fourth status poll, 5 s after the third")
                assert max(panels.values()) <= 1, panels
            finally:
                proc.send_signal(signal.SIGCONT)
            await page.wait_for_function(connected, polling=POLL_MS, timeout=30_000)
            # ... and the panels go on polling once the server answers again
            before = dict(panels)
            await wait_for(lambda: all(panels[p] > before[p] for p in panels), 30, "the panels' polls after the stop")
            await browser.close()
    finally:
        proc.send_signal(signal.SIGCONT)
        stop_process(proc)
    assert [e for e in errors if "ERR_CONNECTION_REFUSED" not in e] == [], errors


def test_hung_server_while_a_log_downloads(udp_port, tcp_port, tmp_path):
    asyncio.run(asyncio.wait_for(hung_log_scenario(udp_port, tcp_port, tmp_path), 240))


async def hung_log_scenario(udp_port: int, port: int, tmp_path) -> None:
    """A page following an onboard log download (a 1-s poll of GET /api/onboard-logs) whose
    server stops answering (gcs serve stopped with SIGSTOP) keeps one request waiting, not one
    more each second, and goes on following the download when the server is back."""
    import httpx

    errors: list[str] = []
    command = [sys.executable, "-m", "gcs", "serve", "--connect", f"udpin:127.0.0.1:{udp_port}", "--port", str(port)]
    serve = subprocess.Popen(
        [*command, "--token", "t0k", "--record-dir", str(tmp_path), "--viser-port", str(free_port(socket.SOCK_STREAM))],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    # log 1: an earlier five-minute flight, tens of seconds to download
    command = [sys.executable, "-m", "gcs", "sim", "--profile", "pixhawk", "--flight-log", "300"]
    sim = subprocess.Popen(
        [*command, "--link", f"udpout:127.0.0.1:{udp_port}"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        deadline = time.monotonic() + 120
        async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{port}", headers={"X-GCS-Token": "t0k"}) as api:
            while True:
                try:
                    if (await api.get("/api/status")).json()["link"]["state"] == "connected":
                        break
                except httpx.TransportError:
                    pass
                assert time.monotonic() < deadline and serve.poll() is None, "gcs serve never heard the vehicle"
                await asyncio.sleep(0.2)
            assert (await api.post("/api/onboard-logs/download", json={"log": 1})).status_code == 202
        async with async_playwright() as pw:
            browser = await launch_chromium(pw)
            page = await open_page(browser, errors)
            await open_dashboard(page, f"http://127.0.0.1:{port}/", PANELS_READY)
            await page.click("#tabs button[data-tab=sessions]")
            await page.locator("#onboard-log-status", has_text="log 1:").wait_for(timeout=60_000)
            polls: list[str] = []
            page.on("request", lambda r: "/api/onboard-logs" in r.url and polls.append(r.url))
            serve.send_signal(signal.SIGSTOP)
            try:
                await page.wait_for_function(
                    "document.querySelector('#link-state').textContent === 'server unreachable'",
                    polling=POLL_MS,
                    timeout=20_000,
                )
                # 5 s and more without an answer: one request waiting (5 on the old page)
                assert len(polls) <= 1, polls
            finally:
                serve.send_signal(signal.SIGCONT)
            await page.locator("#onboard-log-status", has_text="downloaded").wait_for(timeout=180_000)
            await browser.close()
    finally:
        serve.send_signal(signal.SIGCONT)
        stop_process(sim)
        stop_process(serve)
    assert [e for e in errors if "ERR_CONNECTION_REFUSED" not in e] == [], errors


def test_onboard_log_download_followed(udp_port, tmp_path):
    asyncio.run(asyncio.wait_for(onboard_log_scenario(udp_port, tmp_path), 240))


async def onboard_log_scenario(udp_port: int, tmp_path) -> None:
    """A page opened while an onboard log downloads (a reload, or another page) shows its progress
    from the start, and a read-only one keeps its button disabled when it ends (the old page said
    nothing of the download, and enabled the button of a read-only page at its end). A network
    blip (the browser offline for a few polls) is said once and the page goes on following: the
    old page stopped at the first failed request, frozen on the part-done download."""
    import httpx

    errors: list[str] = []
    # log 1: an earlier two-minute flight, some seconds to download
    command = [sys.executable, "-m", "gcs", "sim", "--profile", "pixhawk", "--flight-log", "120"]
    sim = subprocess.Popen(
        [*command, "--link", f"udpout:127.0.0.1:{udp_port}"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        async with (
            running_station(f"udpin:127.0.0.1:{udp_port}", sessions_dir=str(tmp_path), record=True) as station,
            dashboard(station, viser=False) as server,
            async_playwright() as pw,
        ):
            await wait_for(lambda: station.link.target_system is not None, 30, "the vehicle's heartbeat")
            async with httpx.AsyncClient(
                base_url=f"http://127.0.0.1:{server.port}", headers=server.auth_headers
            ) as api:
                assert (await api.post("/api/onboard-logs/download", json={"log": 1})).status_code == 202
            browser = await launch_chromium(pw)
            page = await open_page(browser, errors)
            await open_dashboard(page, f"http://127.0.0.1:{server.port}/", PANELS_READY)  # no token: read-only
            await page.click("#tabs button[data-tab=sessions]")
            status = page.locator("#onboard-log-status", has_text="log 1")
            try:
                await status.wait_for(timeout=30_000)
            except PlaywrightTimeout:
                shown = await page.text_content("#onboard-log-status")
                raise AssertionError(f"page says {shown!r} of {station.onboard_logs.progress}") from None
            failed: list[str] = []
            page.on("requestfailed", lambda r: "/api/onboard-logs" in r.url and failed.append(r.url))
            await page.context.set_offline(True)
            try:
                await wait_for(lambda: len(failed) >= 3, 20, "three failed polls")
            finally:
                await page.context.set_offline(False)
            shown = await page.text_content("#onboard-log-status")
            assert station.onboard_logs.progress.state == "downloading", "the blip came too late"
            assert shown.count("still following") == 1, shown
            await page.locator("#onboard-log-status", has_text="downloaded").wait_for(timeout=120_000)
            assert await page.is_disabled("#onboard-log-btn")
            await browser.close()
    finally:
        stop_process(sim)
    assert [e for e in errors if "ERR_INTERNET_DISCONNECTED" not in e] == [], errors


async def zoom_says_live(page) -> None:
    """A drag on a plot holds that stretch: the button beside the window then reads "live" (what a
    click on it does), as after "pause"; it read "pause" over a view already held."""
    box = await page.locator(".chart .u-over").first.bounding_box()
    y = box["y"] + box["height"] / 2
    await page.mouse.move(box["x"] + 0.3 * box["width"], y)
    await page.mouse.down()
    await page.mouse.move(box["x"] + 0.7 * box["width"], y, steps=5)
    await page.mouse.up()
    await page.wait_for_function("gcsPlots.view !== null", polling=POLL_MS, timeout=20_000)
    assert await page.text_content("#pause") == "live"
    await page.click("#pause")
    await page.wait_for_function("gcsPlots.view === null", polling=POLL_MS, timeout=20_000)
    assert await page.text_content("#pause") == "pause"


def test_a_plain_text_refusal_shows_its_reason(udp_port):
    asyncio.run(asyncio.wait_for(plain_refusal_scenario(udp_port), 240))


async def plain_refusal_scenario(udp_port: int) -> None:
    """The request guard's refusals are plain text, not FastAPI's JSON: a note from another origin
    (the page's request sent on with another site's Origin, the server's answer given back to the
    page) and a gain write are refused, and the page shows the server's reason for each. The old
    page showed "HTTP 403" and "403"."""
    errors: list[str] = []
    async with (
        running_station(f"udpin:127.0.0.1:{udp_port}") as station,  # no vehicle needed
        dashboard(station, viser=False) as server,
        async_playwright() as pw,
    ):
        browser = await launch_chromium(pw)
        page = await open_page(browser, errors)
        await open_dashboard(page, server.url, PANELS_READY)
        await page.click("#tabs button[data-tab=sessions]")
        message = page.locator("#rec-message")

        async def foreign(route) -> None:  # sent by Playwright's own client (Chromium sets Origin itself)
            answer = await route.fetch(headers={**route.request.headers, "origin": "http://elsewhere.example"})
            await route.fulfill(response=answer)

        await page.route("**/api/recording/note", foreign)
        await page.fill("#rec-note", "gusty")
        await page.click("#rec-note-btn")
        await message.filter(has_text="✗").wait_for(timeout=20_000)
        assert await message.text_content() == "✗ refused: requests from another web page's origin are not accepted"
        # ... and a gain write (dashboard.js's requests), refused the same way
        await page.route("**/api/estimators/dcm/gains/*", foreign)
        await page.click("#tabs button[data-tab=live]")
        box = page.locator(GAIN_BOX)
        await box.fill("1")
        await box.press("Tab")
        why = page.locator(
            "#gains details:has(summary[data-estimator=dcm]) .gain:has(input[data-gain=mag_dip_tol]) .why"
        )
        await why.filter(has_text="✗").wait_for(timeout=20_000)
        assert "✗ 1 refused: refused: requests from another web page's origin are not accepted; kept" in (
            await why.text_content()
        )
        await browser.close()
    assert [e for e in errors if "status of 403" not in e] == [], errors


def test_the_3d_view_follows_a_new_viser_port(udp_port, tcp_port):
    asyncio.run(asyncio.wait_for(viser_port_scenario(udp_port, tcp_port), 240))


async def viser_port_scenario(udp_port: int, port: int) -> None:
    """The station's server restarted under an open page on the same port, its 3-D view on another
    (its old one taken, say): the page's 3-D frame follows the port /api/status publishes. The old
    page kept the first port it was given, the frame on a server that is gone."""
    errors: list[str] = []
    first, second = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_STREAM)
    src = "document.getElementById('pose').getAttribute('src') || ''"
    async with running_station(f"udpin:127.0.0.1:{udp_port}") as station, async_playwright() as pw:
        server = DashboardServer(station, port=port, viser_port=first)
        await server.start()
        try:
            browser = await launch_chromium(pw)
            page = await open_page(browser, errors)
            await open_dashboard(page, server.url, f"({src}).includes(':{first}/')")
        finally:
            await server.stop()
        server = DashboardServer(station, port=port, viser_port=second, token=server.token)
        await server.start()
        try:
            try:
                await page.wait_for_function(f"({src}).includes(':{second}/')", polling=POLL_MS, timeout=30_000)
            except PlaywrightTimeout:
                raise AssertionError(f"the 3-D frame shows {await page.evaluate(src)!r}") from None
            await browser.close()
        finally:
            await server.stop()
    assert [e for e in errors if "ERR_CONNECTION_REFUSED" not in e] == [], errors
