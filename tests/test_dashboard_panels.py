"""The dashboard's tuning and sessions panels end to end in headless Chromium (Debian's
/usr/bin/chromium, driven by Playwright): simulator → link → station → uvicorn → page. No mocks:
the page's clicks reach the simulated vehicle's parameter table and the recording folder."""

from __future__ import annotations

import asyncio
import contextlib
import io
import os
import shutil

import pyarrow.parquet as pq
import pytest
from live import CHROMIUM, CHROMIUM_ARGS, PANELS_READY, running_sim, running_station, sim_process, wait_for
from playwright.async_api import TimeoutError as PlaywrightTimeout
from playwright.async_api import async_playwright

from gcs.server.dashboard import DashboardServer


@pytest.fixture(autouse=True)
def _chromium_installed() -> None:
    """A missing browser fails these tests (CI must have it), it never skips them."""
    if not os.path.exists(CHROMIUM):
        pytest.fail(f"{CHROMIUM} missing: run bash .ci/setup")


def unexpected_errors(errors: list[str], statuses: tuple[int, ...]) -> list[str]:
    """Console errors other than Chromium's own line for a response the test provoked on purpose."""
    return [e for e in errors if not any(f"status of {s} " in e for s in statuses)]


async def open_page(pw, url: str, errors: list[str]):
    browser = await pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
    page = await browser.new_page(viewport={"width": 1500, "height": 1000})
    page.on("console", lambda m: m.type == "error" and errors.append(m.text))
    page.on("pageerror", lambda e: errors.append(str(e)))
    await page.goto(url)
    return browser, page


async def set_number(page, selector: str, value: float) -> None:
    """Type a value and leave the box (Tab), as a person does: the browser fires `change`."""
    box = page.locator(selector)
    await box.fill(str(value))
    await box.press("Tab")


# ---- tuning --------------------------------------------------------------------------------
def test_tuning_panel(udp_port, artifacts_dir):
    asyncio.run(asyncio.wait_for(tuning_scenario(udp_port, artifacts_dir), 240))


async def tuning_scenario(udp_port: int, artifacts_dir) -> None:
    errors: list[str] = []
    async with (
        running_station(f"udpin:127.0.0.1:{udp_port}") as station,
        running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad") as sim,
    ):
        server = DashboardServer(station, port=0, viser=False)
        await server.start()
        try:
            await wait_for(lambda: station.link.target_system is not None, 30, "the vehicle's heartbeat")
            before = sim.params.as_dict()
            async with async_playwright() as pw:
                browser, page = await open_page(pw, server.url, errors)
                await page.click("#tabs button[data-tab=tuning]")
                download = page.locator("#param-download-btn")
                await download.wait_for(state="visible", timeout=30_000)
                await download.click()
                current = page.locator("#tuning-table tr.tune[data-param=ATC_RAT_RLL_P] td.cur")
                await page.wait_for_function(
                    "() => { const c = document.querySelector("
                    "'#tuning-table tr.tune[data-param=ATC_RAT_RLL_P] td.cur');"
                    " return c && c.textContent !== '–' && c.textContent !== ''; }",
                    timeout=30_000,
                )
                assert station.params.complete
                assert "downloaded" in await page.text_content("#param-progress-text")
                names = await page.eval_on_selector_all(
                    "#tuning-table tr.tune", "rows => rows.map((r) => r.dataset.param)"
                )
                assert {"ATC_RAT_RLL_P", "ATC_RAT_PIT_P"} <= set(names), names
                start = before["ATC_RAT_RLL_P"]
                assert abs(float(await current.text_content()) - start) < 1e-4
                pre = page.locator("#tuning-table tr.tune[data-param=ATC_RAT_RLL_P] td.pre")
                assert abs(float(await pre.text_content()) - start) < 1e-4

                # A change within the limits reaches the vehicle and is shown verified.
                new = round(start + 0.01, 4)
                result = page.locator("tr.tune-edit[data-param=ATC_RAT_RLL_P] td.result")
                await set_number(page, "tr.tune-edit[data-param=ATC_RAT_RLL_P] input[type=number]", new)
                await page.wait_for_selector(
                    "tr.tune-edit[data-param=ATC_RAT_RLL_P] td.result.verified", timeout=30_000
                )
                assert "verified" in await result.text_content()
                assert abs(sim.params["ATC_RAT_RLL_P"] - new) < 1e-6
                await page.wait_for_function(
                    f"Math.abs(Number(document.querySelector('#tuning-table tr.tune[data-param=ATC_RAT_RLL_P] td.cur')"
                    f".textContent) - {new}) < 1e-5",
                    timeout=20_000,
                )
                assert await page.locator("#tuning-table tr.tune[data-param=ATC_RAT_RLL_P].changed").count() == 1

                # Too large a step is refused, with the server's reason on the page; the vehicle keeps its value.
                await set_number(
                    page, "tr.tune-edit[data-param=ATC_RAT_RLL_P] input[type=number]", round(new + 0.15, 4)
                )
                await page.wait_for_selector("tr.tune-edit[data-param=ATC_RAT_RLL_P] td.result.refused", timeout=30_000)
                text = await result.text_content()
                assert "refused" in text and "more than the largest step 0.02" in text, text
                assert "more than the largest step" in await page.text_content("#tuning-message")
                assert abs(sim.params["ATC_RAT_RLL_P"] - new) < 1e-6

                # The slider moves at most one step from the current value: it cannot ask for a refused write.
                slider = page.locator("tr.tune-edit[data-param=ATC_RAT_PIT_P] input[type=range]")
                lo, hi = await slider.evaluate("el => [Number(el.min), Number(el.max)]")
                assert hi - lo <= 2 * 0.02 + 1e-9
                sent = await slider.evaluate(
                    f"el => {{ el.value = {hi}; el.dispatchEvent(new Event('change', {{bubbles: true}}));"
                    " return Number(el.value); }"
                )
                assert sent > before["ATC_RAT_PIT_P"] + 0.015
                await page.wait_for_selector(
                    "tr.tune-edit[data-param=ATC_RAT_PIT_P] td.result.verified", timeout=30_000
                )
                assert abs(sim.params["ATC_RAT_PIT_P"] - sent) < 1e-6
                await page.locator("#tab-tuning").screenshot(path=str(artifacts_dir / "panel-tuning.png"))

                # Revert all puts back every pre-flight value, in the vehicle.
                await page.click("#tuning-revert")
                try:
                    await page.wait_for_function(
                        "document.querySelector('#tuning-message').textContent.includes('reverted')", timeout=30_000
                    )
                except Exception:
                    raise AssertionError(f"revert: page says {await page.text_content('#tuning-message')!r}") from None
                assert sim.params.as_dict() == before
                await page.wait_for_function(
                    "document.querySelectorAll('#tuning-table tr.tune.changed').length === 0", timeout=20_000
                )
                assert abs(float(await current.text_content()) - start) < 1e-4
                await page.locator("#tab-tuning").screenshot(path=str(artifacts_dir / "panel-tuning-reverted.png"))
                await browser.close()
        finally:
            await server.stop()
    assert unexpected_errors(errors, (422,)) == [], errors


# ---- sessions, replay, what-if -------------------------------------------------------------
@pytest.mark.timeout(480)  # the longest browser scenario: record, export four formats, replay, what-if
def test_sessions_panel(udp_port, tmp_path, artifacts_dir, logs_dir):
    asyncio.run(asyncio.wait_for(sessions_scenario(udp_port, tmp_path, artifacts_dir, logs_dir), 420))


async def sessions_scenario(udp_port: int, root, artifacts_dir, logs_dir) -> None:
    errors: list[str] = []
    async with running_station(f"udpin:127.0.0.1:{udp_port}", sessions_dir=str(root), record=True) as station:
        server = DashboardServer(station, port=0, viser=False)
        await server.start()
        try:
            async with async_playwright() as pw:
                browser, page = await open_page(pw, server.url, errors)
                async with sim_process(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad", speed=4.0):
                    await page.click("#tabs button[data-tab=sessions]")
                    await page.wait_for_function(
                        "document.querySelector('#rec-status').textContent.includes('recording')", timeout=30_000
                    )
                    assert str(root) in await page.text_content("#rec-status")
                    assert "REC" in await page.text_content("#rec-pill")
                    await page.fill("#rec-note", "gusty, swapped props")
                    await page.click("#rec-note-btn")
                    await page.wait_for_function(
                        "document.querySelector('#rec-message').textContent.includes('note added')", timeout=20_000
                    )
                    await wait_for(lambda: station.estimation.pipeline.imu_samples > 600, 60, "IMU samples")
                    await page.wait_for_function(
                        "document.querySelector('#rec-status').textContent.match(/[1-9][0-9.]* (KiB|MiB)/)",
                        timeout=30_000,
                    )
                    await page.locator("#tab-sessions").screenshot(
                        path=str(artifacts_dir / "panel-sessions-recording.png")
                    )
                    await page.click("#rec-stop")
                    await page.wait_for_function(  # listed, closed (the open session was listed while recording)
                        "(() => { const r = document.querySelectorAll('#sessions-table tr[data-session]');"
                        " return r.length === 1 && !r[0].textContent.includes('(open)'); })()",
                        timeout=30_000,
                    )
                await page.wait_for_function(
                    "document.querySelector('#rec-status').textContent.includes('stopped')", timeout=20_000
                )
                assert await page.locator("#rec-stop").is_disabled()
                assert await page.locator("#sessions-table tr[data-session]").count() == 1
                name = await page.get_attribute("#sessions-table tr[data-session]", "data-session")
                row = await page.text_content("#sessions-table tr[data-session]")
                assert " s" in row and ("KiB" in row or "MiB" in row), row

                # The export links work from the page: the CSV parses, the Parquet has the same rows.
                href = await page.get_attribute("#sessions-table tr[data-session] a.export-csv", "href")
                csv = await page.evaluate(
                    "(href) => fetch(href).then((r) => r.ok ? r.text() : 'HTTP ' + r.status)", href
                )
                lines = csv.splitlines()
                assert lines[0] == '"wall_time","t","source","roll_deg","pitch_deg","yaw_deg"', lines[:2]
                assert len(lines) > 100 and all(len(line.split(",")) == 6 for line in lines[1:50])
                href = await page.get_attribute("#sessions-table tr[data-session] a.export-parquet", "href")
                data = await page.evaluate(
                    "(href) => fetch(href).then((r) => r.arrayBuffer()).then((b) => Array.from(new Uint8Array(b)))",
                    href,
                )
                assert pq.read_table(io.BytesIO(bytes(data))).num_rows == len(lines) - 1
                # ... and the MAT and MCAP links (one per format of the export route) download those files.
                for fmt, magic in (("mat", b"MATLAB 5.0 MAT-file"), ("mcap", b"\x89MCAP0\r\n")):
                    href = await page.get_attribute(f"#sessions-table tr[data-session] a.export-{fmt}", "href")
                    data = await page.evaluate(
                        "(href) => fetch(href).then((r) => r.arrayBuffer()).then((b) => Array.from(new Uint8Array(b)))",
                        href,
                    )
                    assert bytes(data).startswith(magic), (fmt, bytes(data[:20]))

                # Logs from other tools in the recording folder are offered as sources too (a copy:
                # a link to a file elsewhere is neither opened nor listed, docs/security.md).
                shutil.copyfile(logs_dir / "ardupilot-fragment.bin", root / "fragment.bin")
                await page.click("#sessions-refresh")
                await page.wait_for_selector(
                    "#whatif-source option[value='fragment.bin']", state="attached", timeout=20_000
                )

                # Replay opens in its own view (the session row's link), never in the live plots.
                href = await page.get_attribute("#sessions-table tr[data-session] a.replay", "href")
                assert href == f"replay.html?source={name}", href
                assert await page.get_attribute("#replay-link", "href") == "replay.html"
                received = await page.evaluate("gcsStats.received.onboard || 0")
                replay = await browser.new_page(viewport={"width": 1366, "height": 768})
                replay.on("pageerror", lambda e: errors.append(str(e)))
                await replay.goto(f"http://127.0.0.1:{server.port}/{href}")
                await replay.wait_for_function("['playing', 'error'].includes(gcsReplay.state)", timeout=60_000)
                assert await replay.evaluate("gcsReplay.error") is None
                await replay.select_option("#replay-speed", "4")
                await replay.wait_for_function("(gcsReplay.added.dcm || 0) > 50", timeout=30_000)
                await replay.screenshot(path=str(artifacts_dir / "replay-view-session.png"))
                await replay.close()
                assert await page.evaluate("gcsStats.received.onboard || 0") == received  # the simulator is gone

                # What-if: a table of old vs new RMS and the new output over the old one.
                await page.click("#tabs button[data-tab=whatif]")
                await page.select_option("#whatif-source", name)
                await page.select_option("#whatif-estimator", "dcm")
                await page.fill("#whatif-gains input[data-gain=kp_rp]", "0.9")
                await page.click("#whatif-run")
                await page.wait_for_selector("#whatif-table tr[data-reference]", timeout=30_000)
                refs = await page.eval_on_selector_all(
                    "#whatif-table tr[data-reference]", "rows => rows.map((r) => r.dataset.reference)"
                )
                assert {"onboard", "truth"} <= set(refs), refs
                cells = await page.eval_on_selector_all(
                    "#whatif-table tr[data-reference=truth] td", "tds => tds.map((t) => t.textContent)"
                )
                assert len(cells) == 7 and cells[1] != cells[2], cells
                assert await page.locator("#whatif-plot canvas").count() >= 1
                await page.locator("#tab-whatif").screenshot(path=str(artifacts_dir / "panel-whatif.png"))

                # A recording failure (a full disk) is shown on the page, whichever tab is open.
                station.recorder.report_error("cannot write session: No space left on device")
                await page.wait_for_function(
                    "document.querySelector('#panel-warnings').textContent.includes('No space left')", timeout=20_000
                )
                await page.click("#tabs button[data-tab=sessions]")
                assert "No space left" in await page.text_content("#rec-error")
                await page.screenshot(path=str(artifacts_dir / "dashboard-recording-failed.png"))
                await browser.close()
        finally:
            await server.stop()
    assert errors == [], errors


# ---- a write the vehicle took but did not echo -----------------------------------------------
def test_a_write_without_echo_can_be_reverted(udp_port, artifacts_dir):
    asyncio.run(asyncio.wait_for(unechoed_scenario(udp_port, artifacts_dir), 240))


ROW, CURRENT = "tr.tune-edit[data-param=ATC_RAT_RLL_P]", "#tuning-table tr.tune[data-param=ATC_RAT_RLL_P] td.cur"


@contextlib.asynccontextmanager
async def tuning_tab(udp_port: int, errors: list[str]):
    """A station, the pixhawk simulator and a page on the Tuning tab with the parameters downloaded:
    (the simulator, the page, the start-up URL with the token)."""
    async with (
        running_station(f"udpin:127.0.0.1:{udp_port}") as station,
        running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad") as sim,
    ):
        server = DashboardServer(station, port=0, viser=False)
        await server.start()
        try:
            await wait_for(lambda: station.link.target_system is not None, 30, "the vehicle's heartbeat")
            async with async_playwright() as pw:
                browser, page = await open_page(pw, server.url, errors)
                await page.click("#tabs button[data-tab=tuning]")
                await page.locator("#param-download-btn").click(timeout=30_000)
                await page.wait_for_function(
                    f"(document.querySelector('{CURRENT}')?.textContent || '–') !== '–'", timeout=30_000
                )
                yield sim, page, server.url
                await browser.close()
        finally:
            await server.stop()


async def unechoed_scenario(udp_port: int, artifacts_dir) -> None:
    """The vehicle takes a write and its echo is lost (every PARAM_VALUE dropped, as by a radio
    that loses the downlink): the page says the write's result is unknown, the row's value is
    unknown and "Revert all" is offered, which puts the pre-flight value back. The old page
    showed the old value as current, the row unchanged and "Revert all" disabled, with the new
    gain on the vehicle."""
    errors: list[str] = []
    async with tuning_tab(udp_port, errors) as (sim, page, _):
        start = sim.params["ATC_RAT_RLL_P"]
        assert await page.is_disabled("#tuning-revert")
        sim.param_drop = 1.0
        new = round(start + 0.01, 4)
        await set_number(page, f"{ROW} input[type=number]", new)
        await page.wait_for_selector(f"{ROW} td.result.timeout", timeout=30_000)
        assert "the value on the vehicle is unknown" in await page.text_content(f"{ROW} td.result")
        assert abs(sim.params["ATC_RAT_RLL_P"] - new) < 1e-6  # the vehicle took it
        try:
            await page.wait_for_function("!document.querySelector('#tuning-revert').disabled", timeout=20_000)
        except PlaywrightTimeout:
            shown = await page.text_content(CURRENT)
            raise AssertionError(f"Revert all stays disabled; the page shows {shown!r} as current") from None
        assert (await page.text_content(CURRENT)).startswith("?"), await page.text_content(CURRENT)
        await page.locator("#tab-tuning").screenshot(path=str(artifacts_dir / "panel-tuning-unechoed.png"))

        sim.param_drop = 0.0
        await page.click("#tuning-revert")
        await page.wait_for_function(
            "document.querySelector('#tuning-message').textContent.includes('reverted')", timeout=30_000
        )
        assert abs(sim.params["ATC_RAT_RLL_P"] - start) < 1e-6
        await page.wait_for_function(
            f"Math.abs(Number(document.querySelector('{CURRENT}').textContent) - {start}) < 1e-5"
            " && document.querySelector('#tuning-revert').disabled",
            timeout=20_000,
        )
    assert unexpected_errors(errors, (504,)) == [], errors


# ---- Revert all while a slider's value waits to be written ------------------------------------
def test_revert_all_drops_a_slider_value_not_yet_sent(udp_port):
    asyncio.run(asyncio.wait_for(revert_queued_scenario(udp_port), 240))


async def revert_queued_scenario(udp_port: int) -> None:
    """Arrow presses on a slider while its first write waits for the vehicle's echo queue the
    newest value; "Revert all" clicked then drops it and says so, and the vehicle ends at its
    pre-flight value. The queued value was written after the revert, which the page had
    reported "reverted and verified"."""
    errors: list[str] = []
    async with tuning_tab(udp_port, errors) as (sim, page, _):
        start = sim.params["ATC_RAT_RLL_P"]
        puts: list[str] = []
        page.on("request", lambda r: r.method == "PUT" and puts.append(r.post_data))
        # a change to revert (Revert all is offered only then)
        pitch = sim.params["ATC_RAT_PIT_P"]
        pitch_box = "tr.tune-edit[data-param=ATC_RAT_PIT_P] input[type=number]"
        await set_number(page, pitch_box, round(pitch + 0.01, 4))
        await page.wait_for_selector("tr.tune-edit[data-param=ATC_RAT_PIT_P] td.result.verified", timeout=30_000)
        await page.wait_for_function("!document.querySelector('#tuning-revert').disabled", timeout=20_000)
        puts.clear()
        sim.param_drop = 1.0  # the next write waits for its echo (1 s a try)
        slider = page.locator(f"{ROW} input[type=range]")
        await slider.focus()
        await page.keyboard.press("ArrowRight")
        await page.wait_for_selector(f"{ROW} td.result.pending", timeout=20_000)
        for _ in range(4):
            await page.keyboard.press("ArrowRight")
        await page.click("#tuning-revert")
        await wait_for(lambda: len(puts) == 1, 20, "the first write sent")
        sim.param_drop = 0.0  # its next try is echoed, then the revert's write
        await page.wait_for_function(
            "document.querySelector('#tuning-message').textContent.includes('reverted')", timeout=30_000
        )
        message = await page.text_content("#tuning-message")
        assert "not sent: ATC_RAT_RLL_P = 0.14" in message, message
        await page.wait_for_function(
            f"!document.querySelector('{ROW} td.result').className.includes('pending')", timeout=20_000
        )
        assert len(puts) == 1, puts
        assert abs(sim.params["ATC_RAT_RLL_P"] - start) < 1e-6
        assert abs(sim.params["ATC_RAT_PIT_P"] - pitch) < 1e-6
    assert errors == [], errors


# ---- two pages on the Tuning tab -------------------------------------------------------------
def test_a_second_tuning_page_follows_and_cannot_undo_a_write(udp_port):
    asyncio.run(asyncio.wait_for(two_pages_scenario(udp_port), 240))


async def two_pages_scenario(udp_port: int) -> None:
    """Page B's timers are paused (no poll of its own runs): it shows page A's write at once, pushed
    over /ws/live. With its WebSocket closed it no longer hears, and a slider move there, made from
    the value it last saw, is refused ("not written") instead of putting that value back. The old
    page B showed A's write only at its 5-s poll, and its slider move undid it."""
    errors: list[str] = []
    async with tuning_tab(udp_port, errors) as (sim, page, url):
        start = sim.params["ATC_RAT_RLL_P"]
        other = await page.context.browser.new_page(viewport={"width": 1500, "height": 1000})
        other.on("pageerror", lambda e: errors.append(str(e)))
        await other.clock.install()
        await other.goto(url)
        await other.wait_for_function(PANELS_READY)
        await other.click("#tabs button[data-tab=tuning]")
        await other.wait_for_function(f"(document.querySelector('{CURRENT}')?.textContent || '–') !== '–'")
        await other.clock.pause_at(await other.evaluate("Date.now() + 1"))

        first = round(start + 0.01, 4)
        await set_number(page, f"{ROW} input[type=number]", first)
        await page.wait_for_selector(f"{ROW} td.result.verified", timeout=30_000)
        shows = f"Math.abs(Number(document.querySelector('{CURRENT}').textContent) - %s) < 1e-5"
        try:
            await other.wait_for_function(shows % first, timeout=20_000)
        except PlaywrightTimeout:
            raise AssertionError(f"page B still shows {await other.text_content(CURRENT)!r}") from None
        lo, hi = await other.locator(f"{ROW} input[type=range]").evaluate("el => [Number(el.min), Number(el.max)]")
        assert abs((lo + hi) / 2 - first) < 1e-5, (lo, hi)  # its slider moves from the new value

        await other.evaluate("gcsWs.onclose = null; gcsWs.close()")  # B hears no more
        second = round(start + 0.02, 4)
        await set_number(page, f"{ROW} input[type=number]", second)
        await page.wait_for_function(f"document.querySelector('{ROW} td.result').textContent.includes('→ {second}')")
        assert abs(sim.params["ATC_RAT_RLL_P"] - second) < 1e-6
        await other.locator(f"{ROW} input[type=range]").evaluate(
            f"el => {{ el.value = {start}; el.dispatchEvent(new Event('change', {{bubbles: true}})); }}"
        )
        await other.wait_for_selector(f"{ROW} td.result.stale, {ROW} td.result.verified", timeout=30_000)
        text = await other.text_content(f"{ROW} td.result")
        assert "changed elsewhere" in text and f"it is {second} now" in text, text
        assert abs(sim.params["ATC_RAT_RLL_P"] - second) < 1e-6  # A's write stands
        await other.wait_for_function(shows % second, timeout=20_000)  # and B shows it now
    assert unexpected_errors(errors, (412,)) == [], errors
