"""Replay beside live, never instead of it (issue 12, item 2), end to end: the simulator in its
own process → UDP → station → uvicorn → two headless Chromium pages. One viewer opens a replay in
its own view (replay.html); the other keeps the live page. The replay is computed in the station's
worker process and played by the page that asked: the live viewer keeps its samples, receives
none of the replay's, and the link's IMU rate holds; a what-if over a 10-minute session during
the flight does not make the link go lost."""

from __future__ import annotations

import asyncio
import shutil
import time
from collections import Counter
from pathlib import Path

import httpx
import pytest
from live import dashboard, launch_chromium, open_page, running_station, sim_process, wait_for
from playwright.async_api import async_playwright

from gcs.runtime.snapshots import StationSnapshot
from gcs.sim.recording import write_tlog

#: Share of the live samples the live viewer must keep while another viewer replays.
KEPT = 0.95
#: Largest departure of the link's IMU rate from the requested rate while a replay runs (at every
#: 5-s sample) or a what-if runs (its mean).
RATE_TOLERANCE = 0.10
#: Lowest 5-s IMU rate allowed during a what-if (share of requested): a starved link shows 0 and
#: then goes lost. On a 2-core machine at load 14 windows of 0.7 were seen with no what-if at all.
FLOOR = 0.6


@pytest.fixture(scope="module")
def flights(tmp_path_factory) -> Path:
    """Where the simulated flights (.tlog) are written, once per module."""
    return tmp_path_factory.mktemp("flights")


def flight(folder: Path, name: str, seconds: float) -> Path:
    path = folder / name
    return path if path.exists() else write_tlog(path, seconds)


class LinkWatch:
    """The link's state changes and the IMU stream's achieved/requested rate at every published
    snapshot (once a second), between start() and stop()."""

    def __init__(self, station) -> None:
        self.station = station
        self.states: list[str] = []
        self.ratios: list[tuple[float, float]] = []  # (achieved, requested)
        self.on = False
        station.link.state_changed.connect(lambda old, new: self.on and self.states.append(new))
        station.published.connect(self._published)

    def _published(self, snap: StationSnapshot) -> None:
        if not self.on:
            return
        self.states.append(snap.link.state)
        for name, rate in snap.streams.messages.items():
            if "IMU" in name and rate.requested_hz:
                self.ratios.append((rate.achieved_hz, rate.requested_hz))

    def rates(self) -> tuple[float, float, float]:
        """(min, max achieved, requested) over the watch."""
        achieved = [a for a, _ in self.ratios]
        return min(achieved), max(achieved), self.ratios[0][1]


class LoopLag:
    """The station's event loop's worst lateness (s): how long a 50 ms sleep overran, the longest
    the link reader could have waited."""

    def __init__(self) -> None:
        self.worst = 0.0
        self.task: asyncio.Task | None = None

    async def _run(self) -> None:
        while True:
            start = time.monotonic()
            await asyncio.sleep(0.05)
            self.worst = max(self.worst, time.monotonic() - start - 0.05)

    def start(self) -> None:
        self.task = asyncio.create_task(self._run())

    def stop(self) -> None:
        assert self.task is not None
        self.task.cancel()


def link_imu_steady(station) -> bool:
    msgs = station.snapshot.streams.messages
    return any("IMU" in n and r.ratio is not None and r.ratio > 1 - RATE_TOLERANCE / 2 for n, r in msgs.items())


@pytest.mark.timeout(660)
def test_replay_opens_beside_live_and_the_live_viewer_keeps_its_samples(udp_port, flights, artifacts_dir, tmp_path):
    asyncio.run(asyncio.wait_for(replay_beside_live(udp_port, flights, artifacts_dir, tmp_path), 600))


async def replay_beside_live(udp_port: int, flights: Path, artifacts_dir: Path, tmp_path: Path) -> None:
    root = tmp_path / "sessions"
    root.mkdir()
    shutil.copy(flight(flights, "short.tlog", 30), root / "short.tlog")  # a symlink out of the folder is refused
    errors: list[str] = []
    async with running_station(f"udpin:127.0.0.1:{udp_port}", sessions_dir=str(root), record=True) as station:
        async with dashboard(station, viser=False) as server:
            emitted: Counter[str] = Counter()
            station.points.connect(lambda points: emitted.update(p.source for p in points))
            watch, baseline = LinkWatch(station), LinkWatch(station)
            async with (
                sim_process(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad"),
                async_playwright() as pw,
            ):
                await wait_for(lambda: link_imu_steady(station), 90, "the IMU stream at its requested rate")
                browser = await launch_chromium(pw)
                live = await open_page(browser, errors)
                viewer = await open_page(browser, errors)
                before_live_page = Counter(emitted)
                await live.goto(server.url)
                await live.wait_for_function("(gcsStats.received.onboard || 0) > 100", timeout=60_000)
                baseline.on = True
                await wait_for(lambda: len(baseline.ratios) >= 8, 60, "8 s of live rates")
                baseline.on = False

                # From here on: what the station emits against what the live page receives.
                before_page = await live.evaluate("({...gcsStats.received})")
                before_station = Counter(emitted)
                dropped_before = await live.evaluate("gcsStats.dropped")
                watch.on = True
                lag = LoopLag()
                lag.start()
                await viewer.goto(f"http://127.0.0.1:{server.port}/replay.html?source=short.tlog")
                await viewer.wait_for_function("['playing', 'error'].includes(gcsReplay.state)", timeout=240_000)
                assert await viewer.evaluate("gcsReplay.state") == "playing", await viewer.evaluate("gcsReplay.error")
                computed = len(watch.ratios)  # rates while the worker computed the replay: before this
                await viewer.select_option("#replay-speed", "4")
                await viewer.wait_for_function("gcsReplay.position > 15", timeout=60_000)
                await viewer.screenshot(path=str(artifacts_dir / "replay-view.png"))
                await live.screenshot(path=str(artifacts_dir / "replay-live-beside.png"))
                watch.on = False
                lag.stop()
                after_station = Counter(emitted)
                expected = {s: after_station[s] - before_station[s] for s in ("onboard", "dcm", "ekf")}

                # Every live sample of the period reaches the live page (allowing for frames in flight) ...
                js = "(e) => Object.entries(e).every(([s, n]) => (gcsStats.received[s] || 0) - (%s[s] || 0) >= %s * n)"
                await live.wait_for_function(js % (before_page, KEPT), arg=expected, timeout=30_000)
                got = await live.evaluate("({...gcsStats.received})")
                now = Counter(emitted)  # read after the page: the page cannot be ahead of it
                kept = {s: min(1.0, (got.get(s, 0) - before_page.get(s, 0)) / n) for s, n in expected.items()}
                dropped = await live.evaluate("gcsStats.dropped") - dropped_before
                # ... and nothing else: the replay's points never reach a live viewer.
                for s in ("onboard", "truth", "dcm", "kf", "ekf"):
                    assert got.get(s, 0) <= now[s] - before_live_page[s], (s, got, now, before_live_page)
                # The replay page has the replay: its own samples, its own error table.
                added = await viewer.evaluate("gcsReplay.added")
                assert added["onboard"] > 400 and added["dcm"] > 400, added
                assert await viewer.locator("#replay-table tr[data-reference=onboard]").count() == 3
                assert await viewer.locator("#charts canvas").count() >= 6
                await browser.close()
    low, high, requested = watch.rates()
    mean = sum(a for a, _ in watch.ratios) / len(watch.ratios)
    print(f"live samples kept {kept}, hub dropped {dropped} for the live page")
    rates = [round(a, 1) for a, _ in watch.ratios]
    print(f"IMU rates while computing {rates[:computed]}, while playing {rates[computed:]}")
    print(f"IMU rate during the replay {low:.1f}..{high:.1f} Hz, mean {mean:.1f}, of {requested:.0f} requested")
    print(f"station loop's worst lateness during it: {1000 * lag.worst:.0f} ms")
    print(f"IMU rate before it (live page only) {baseline.rates()[0]:.1f}..{baseline.rates()[1]:.1f} Hz")
    assert min(kept.values()) >= KEPT, kept
    # The link's IMU rate never more than 10 % short of requested: at every published sample (once
    # a second, over the link's 5-s window), while the worker computes the replay and while it
    # plays. A window over the rate is the simulator (its own process) catching up on samples it
    # was late with, as starved by the machine's load before the window (seen once in a CI run:
    # 55.4 Hz twice after a steady 50.0): the station cannot count more than arrived, and its own
    # stall would show first as a short window. Over the whole watch the mean stays within 10 %.
    short = [round(a, 1) for a, r in watch.ratios if a < (1 - RATE_TOLERANCE) * r]
    assert not short, (short, requested, rates)
    assert abs(mean - requested) <= RATE_TOLERANCE * requested, (mean, requested, rates)
    assert set(watch.states) == {"connected"}, watch.states
    assert errors == [], errors


@pytest.mark.timeout(660)  # writes the 10-minute flight first (about 90 s on a loaded machine)
def test_whatif_over_a_ten_minute_session_during_a_flight_keeps_the_link(udp_port, flights, tmp_path):
    asyncio.run(asyncio.wait_for(whatif_during_flight(udp_port, flights, tmp_path), 600))


async def whatif_during_flight(udp_port: int, flights: Path, tmp_path: Path) -> None:
    root = tmp_path / "sessions"
    root.mkdir()
    shutil.copy(flight(flights, "long.tlog", 600), root / "long.tlog")
    async with running_station(f"udpin:127.0.0.1:{udp_port}", sessions_dir=str(root), record=True) as station:
        async with dashboard(station, viser=False) as server:
            watch = LinkWatch(station)
            async with (
                sim_process(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad"),
                httpx.AsyncClient(base_url=f"http://127.0.0.1:{server.port}", headers=server.auth_headers) as api,
            ):
                await wait_for(lambda: link_imu_steady(station), 90, "the IMU stream at its requested rate")
                watch.on = True
                lag = LoopLag()
                lag.start()
                started = time.monotonic()
                res = await api.post(
                    "/api/whatif",
                    json={"source": "long.tlog", "estimator": "dcm", "gains": {"kp_rp": 0.9}},
                    timeout=400,
                )
                assert res.status_code == 200, res.text
                assert {r["reference"] for r in res.json()["table"]} >= {"onboard", "truth"}
                elapsed = time.monotonic() - started
                watch.on = False
                lag.stop()
    low, high, requested = watch.rates()
    print(f"what-if over 600 s in {elapsed:.1f} s; IMU rate {low:.1f}..{high:.1f} Hz of {requested:.0f}")
    print(f"link states during it: {sorted(set(watch.states))}; loop's worst lateness {1000 * lag.worst:.0f} ms")
    assert "lost" not in watch.states and set(watch.states) == {"connected"}, watch.states
    mean = sum(a for a, _ in watch.ratios) / len(watch.ratios)
    print(f"mean IMU rate during it {mean:.1f} Hz")
    assert low >= FLOOR * requested, (low, requested)
    assert abs(mean - requested) <= RATE_TOLERANCE * requested, (mean, requested)
