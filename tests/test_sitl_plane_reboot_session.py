"""The real ArduPlane SITL (../shared/sitl) rebooted by MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN in the
middle of a recorded session, as an engineer reboots after a parameter change: the station redials
its TCP port and the one session holds two boots, the vehicle's clock from 0 again in the second.
Afterwards the what-if (its "old" row: the recorded gains), `gcs replay --fast` (whole-run arrays)
and `gcs report` (its error plot, and its attitude and error lines) must score and draw each boot
against itself, as the live comparison and the session's whole-run errors
(`gcs.open_session(...).errors()`) do. Before, they searched one estimator's outputs across the two
boots: the what-if's old row and `gcs replay --fast` read ekf-truth yaw RMS 2.95-2.97° for a session
whose live and whole-run figure was 4.56°, and the report drew lines from the end of the first boot
back to the start of the second. The replay view (replay.html) must play the boots one after the
other: played to the end it showed only one source (every other one cleared by the plots' restart
at the reboot), as it handed each source's samples of both boots to the plots at once. So must the
what-if's chart, whose x must ascend."""

from __future__ import annotations

import asyncio

import matplotlib.axes
import numpy as np
import pytest
import scipy.io
from live import POLL_MS, dashboard, launch_chromium, open_page, running_station, served_api, wait_for
from mcap.reader import make_reader
from playwright.async_api import async_playwright
from test_sitl_copter import _command, sitl_process

from gcs.commands.cli import main
from gcs.core.samples import REBOOT_CLOCK_JUMP
from gcs.mavlink.dialect import mavlink
from gcs.runtime.replay import ReplaySession, session_table, whole_table
from gcs.sessions import report
from gcs.sessions.contents import open_contents
from gcs.sessions.sources import open_source
from gcs.sessions.whatif import what_if

pytestmark = pytest.mark.slow

AXES = ("roll", "pitch", "yaw")
#: The vehicle time of the session's gain change in each boot (the fixture's).
CHANGED: list[float] = []
#: Vehicle seconds of each boot recorded: past the EKF's alignment (yaw converging) in both.
BOOT_S = 20.0


@pytest.fixture(scope="module")
def rebooted_session(tmp_path_factory):
    """A session folder of ArduPlane SITL at real time over TCP, rebooted once after BOOT_S s."""
    folder = tmp_path_factory.mktemp("rebooted")

    async def scenario(port: int):
        async with running_station(
            f"tcp:127.0.0.1:{port}", sessions_dir=str(folder / "sessions"), record=True
        ) as station:
            clock = station.vehicle.clock
            await wait_for(lambda: (clock.last or 0.0) > BOOT_S, 120, "the first boot's clock")
            changed = [clock.last]  # a gain change in each boot, at this vehicle time
            station.set_gain("dcm", "kp_rp", 0.25, "test")
            _command(station, mavlink.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1)
            await wait_for(lambda: clock.reboots == 1, 120, "the second boot (its clock from 0)")
            await wait_for(lambda: (clock.last or 0.0) > BOOT_S, 120, "the second boot's clock")
            changed.append(clock.last)
            station.set_gain("dcm", "kp_rp", 0.3, "test")
            await wait_for(lambda: (clock.last or 0.0) > BOOT_S + 2, 30, "the second boot after its change")
            return station.recorder.session.folder, changed

    with sitl_process(folder / "sitl", "arduplane", "plane", "plane.parm", 1) as port:
        session, changed = asyncio.run(scenario(port))
    CHANGED.extend(changed)
    return session


@pytest.mark.timeout(360)
def test_what_if_replay_fast_and_report_score_each_boot_of_a_rebooted_plane_alone(rebooted_session, monkeypatch):
    contents = open_contents(rebooted_session)
    onboard = contents.series("onboard")[:, 0]
    assert (np.diff(onboard) < -REBOOT_CLOCK_JUMP).sum() == 1  # one session, two boots
    whole_run = {(r["estimator"], r["reference"]): r for r in contents.errors().to_pylist()}

    # `gcs replay --fast` (whole-run arrays) and the what-if with nothing changed (its "old" row):
    # the table of `gcs replay` (the per-sample pipeline), which no longer scores the new boot's
    # first ATTITUDE (before its first estimate) against the old boot's estimates
    names = ["dcm", "kf", "ekf"]
    replay = ReplaySession(open_source(rebooted_session), 0, names, {})
    replay.run_to_end()
    per_sample = {(r["estimator"], r["reference"]): r for r in session_table(replay.pipeline)}
    rows, _ = whole_table(open_source(rebooted_session), names, {})
    assert len(rows) == len(per_sample) >= 6
    for row in rows:
        expected = per_sample[row["estimator"], row["reference"]]
        assert row["n"] == expected["n"], (row, expected)
        assert row["rms_deg"] == pytest.approx(expected["rms_deg"], rel=1e-9, abs=1e-12), row
    result = what_if(open_source(rebooted_session), "ekf", {"gyro_noise": 0.02})
    old = {row.reference: row.old_rms for row in result.table()}
    assert {"onboard", "truth"} <= set(old)
    assert old == {
        ref: pytest.approx(r["rms_deg"], rel=1e-9, abs=1e-12) for (e, ref), r in per_sample.items() if e == "ekf"
    }
    # the session's whole-run errors (its recorded points, each boot against itself): truth, whose rows
    # the live run and the replay share, as the replay but for the outputs before each boot's first
    # valid one (a few per boot: 6 were seen over the two boots)
    assert 0 <= per_sample["ekf", "truth"]["n"] - whole_run["ekf", "truth"]["n"] <= 5 * 2
    # and each ATTITUDE falls on the same side of the onboard / onboard-unready line live and in the
    # replay, but for those same first outputs (an audit once saw ~88 put on different sides after
    # a reboot; 0 and 3-6 differ in a run of this fixture on 2026-12-06)
    for estimator in names:
        for reference in ("onboard", "onboard-unready"):
            gap = per_sample[estimator, reference]["n"] - whole_run[estimator, reference]["n"]
            assert 0 <= gap <= 5 * 2, (estimator, reference, gap)

    # the report: its error lines are the session's errors, each boot against itself, and no line
    # runs back in time from one boot into the next
    lines: list[tuple[str, np.ndarray, np.ndarray]] = []
    plot = matplotlib.axes.Axes.plot

    def recording_plot(self, *args, **kwargs):
        lines.append((kwargs.get("label", ""), np.asarray(args[0], float), np.asarray(args[1], float)))
        return plot(self, *args, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "plot", recording_plot)
    out = rebooted_session.parent / "report.html"
    report.write_report(str(rebooted_session), str(out))
    for label, t, _ in lines:
        for segment in np.split(t, np.flatnonzero(np.isnan(t))):
            assert np.all(np.diff(segment[np.isfinite(segment)]) >= -REBOOT_CLOCK_JUMP), label
    # what the onboard rows leave out, at each boot's start: both intervals, not one across them
    assert "after a reboot" in out.read_text()
    # the error figure draws each estimator against truth after the attitude figure's lines
    errors = [(label, t, y) for label, t, y in lines if label in ("dcm", "kf", "ekf")]
    for estimator in ("dcm", "kf", "ekf"):
        expected = contents.errors_of(estimator, "truth")
        drawn = [(t, y) for label, t, y in errors if label == estimator][-3:]  # roll, pitch, yaw errors
        assert len(drawn) == 3, estimator
        for k, (t, y) in enumerate(drawn):
            keep = np.isfinite(t)
            np.testing.assert_allclose(t[keep], expected[:, 0], err_msg=estimator)
            np.testing.assert_allclose(y[keep], expected[:, 1 + k], atol=1e-6, err_msg=f"{estimator} axis {k}")


@pytest.mark.timeout(360)
def test_the_replay_view_plays_a_rebooted_plane_boot_after_boot(rebooted_session, udp_port):
    """Played to the end, the replay view holds every source's second boot, as the live page holds
    the new boot after a reboot (plots.js restarts on a clock that went back)."""
    contents = open_contents(rebooted_session)
    series = {s: contents.boot_series(s) for s in ("onboard", "truth", "ahrs2", "dcm", "kf", "ekf")}
    last_boot = {s: data[boot == boot.max(), 0] for s, (data, boot) in series.items()}
    errors: list[str] = []

    async def scenario():
        async with (
            running_station(
                f"udpin:127.0.0.1:{udp_port}", sessions_dir=str(rebooted_session.parent), record=True
            ) as station,
            dashboard(station, viser=False) as server,
            async_playwright() as pw,
        ):
            browser = await launch_chromium(pw)
            page = await open_page(browser, errors)
            await page.goto(f"http://127.0.0.1:{server.port}/replay.html?source={rebooted_session.name}")
            playing = "['playing', 'error'].includes(gcsReplay.state)"
            await page.wait_for_function(playing, polling=POLL_MS, timeout=240_000)
            assert await page.evaluate("gcsReplay.state") == "playing", await page.evaluate("gcsReplay.error")
            await page.select_option("#replay-speed", "0")  # to the end
            await page.wait_for_function("gcsReplay.state === 'finished'", polling=POLL_MS, timeout=60_000)
            held = "Object.fromEntries(Object.entries(gcsPlayer.plots.sources).map(([s, x]) => [s, x.t.slice()]))"
            return await page.evaluate(held)

    held = asyncio.run(scenario())
    assert not errors, errors
    for source, t in last_boot.items():
        np.testing.assert_allclose(held[source], t, atol=1e-4, err_msg=source)  # the replay's: rounded to 0.1 ms


@pytest.mark.timeout(360)
def test_the_what_if_chart_lays_a_rebooted_plane_boot_after_boot(rebooted_session, udp_port):
    """The what-if's chart (uPlot, which wants its x ascending) drew the second boot over the first
    with a line back from the end of one to the start of the other; it now lays the boots one after
    the other on its time axis, its lines broken between them."""

    async def scenario():
        async with (
            running_station(
                f"udpin:127.0.0.1:{udp_port}", sessions_dir=str(rebooted_session.parent), record=True
            ) as station,
            served_api(station) as api,
        ):
            body = {"source": rebooted_session.name, "estimator": "dcm", "gains": {"kp_rp": 0.5}}
            answer = await api.post("/api/whatif", json=body, timeout=240)
            assert answer.status_code == 200, answer.text
            return answer.json()

    view = asyncio.run(scenario())
    t = np.array(view["t"], dtype=float)
    assert np.all(np.diff(t) > 0), t[np.flatnonzero(np.diff(t) <= 0)[:3]]
    gaps = {
        (run, axis): [k for k, v in enumerate(view[run][axis]) if v is None] for run in ("old", "new") for axis in AXES
    }
    (gap,) = gaps["old", "roll"]  # one reboot: the lines break once, in every series at the same place
    assert all(found == [gap] for found in gaps.values()), gaps
    assert t[gap + 1] - t[gap - 1] == pytest.approx(1.0, abs=0.1)  # BOOT_GAP_S from one boot to the next


@pytest.mark.timeout(360)
def test_the_mat_and_mcap_exports_place_each_boots_gain_change_on_its_own_clock(rebooted_session, tmp_path):
    """Gain changes (and every event and comparison row, which have only the host clock) are put on
    the vehicle clock by its offset from the host's: one median offset over the whole session put
    the changes of one of the two boots a boot's length (over 20 s) off. In the MCAP file the second
    boot then follows the first on the one timeline."""
    out = tmp_path / "session.mat"
    assert main(["export", str(rebooted_session), "--format", "mat", "--out", str(out)]) == 0
    changes = scipy.io.loadmat(out, simplify_cells=True)["gain_changes"]
    assert list(changes["new"]) == [0.25, 0.3]
    np.testing.assert_allclose(changes["t"], CHANGED, atol=0.5)

    out = tmp_path / "session.mcap"
    assert main(["export", str(rebooted_session), "--format", "mcap", "--out", str(out)]) == 0
    with open(out, "rb") as f:
        logged = [
            message.log_time / 1e9
            for _, channel, message in make_reader(f).iter_messages(topics=["/events"])
            if b'"gain"' in message.data and b"kp_rp" in message.data
        ]
    # log_time: the second boot laid 1 s after the end of the first (on its own clock it lay over it)
    t = open_contents(rebooted_session).attitude["t"].to_numpy()  # every source's rows, in the order recorded
    cut = np.flatnonzero(np.diff(t) < -REBOOT_CLOCK_JUMP)[0] + 1
    shift = t[:cut].max() + 1.0 - t[cut:].min()
    np.testing.assert_allclose(logged, [CHANGED[0], CHANGED[1] + shift], atol=0.5)
