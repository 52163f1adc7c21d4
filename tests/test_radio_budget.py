"""The 57600-baud telemetry radio: the simulator's SiK radio (bandwidth, buffer, RADIO_STATUS), the
station's budget (predicted rates, back-off on a filling buffer) and a log download through it."""

from __future__ import annotations

import asyncio
import socket
import time

import httpx
import pytest
from live import running_sim, running_station, wait_for

from gcs.commands.status import format_report
from gcs.mavlink.dialect import Encoder, mavlink
from gcs.mavlink.radio import frame_bytes, link_capacity, predict
from gcs.runtime.fleet import Fleet
from gcs.runtime.logdownload import LogDownloader
from gcs.runtime.station import StationConfig
from gcs.runtime.streams import STREAM_GROUPS, StreamPlan
from gcs.server.app import create_app
from gcs.sim import SimVehicle
from gcs.sim.radio import UART_BUFFER_BYTES, SikRadio, fit_radio
from gcs.sim.recording import fly_flight_logs


def test_prediction_fits_the_apm25_streams_into_57600_baud():
    wanted = {k: v for k, v in StreamPlan().for_autopilot("ArduPilot").items() if k not in ("SCALED_IMU2", "AHRS2")}
    budget = 0.8 * link_capacity(57600)
    full = predict(wanted, 1, 1e9, groups=STREAM_GROUPS)
    fitted = predict(wanted, 1, budget, background_bps=300, groups=STREAM_GROUPS)
    assert full.scale == 1.0 and full.total_bps > budget  # 50 Hz IMU + attitude + truth do not fit
    assert fitted.total_bps <= budget < fitted.total_bps + 3 * 50 * 52  # fits, with little left over
    assert fitted.rates["GPS_RAW_INT"] == 5.0 and 5 < fitted.rates["RAW_IMU"] < 50
    assert fitted.rates["RAW_IMU"] == fitted.rates["ATTITUDE"] and fitted.rates["RAW_IMU"].is_integer()
    # a group member costs its group's rate: the barometer rides with the IMU
    assert fitted.cost_bps["SCALED_PRESSURE"] == fitted.rates["RAW_IMU"] * frame_bytes("SCALED_PRESSURE", 1)


def test_vehicles_sharing_a_radio_each_have_their_own_serial_port():
    """Two vehicles sending a burst at the same instant (every stream at one rate falls due
    together): each fits its own autopilot's UART; only a vehicle overfilling its own skips."""
    radio = SikRadio(57600)
    bursts = {sysid: [Encoder(sysid, 1, mavlink1=True).encode(_simstate()) for _ in range(6)] for sysid in (1, 2)}
    assert sum(len(p) for p in bursts[1]) < UART_BUFFER_BYTES < sum(len(p) for b in bursts.values() for p in b)
    for packets in bursts.values():
        for packet in packets:
            radio.offer(packet)
    assert radio.skipped == 0 and radio.queued == sum(len(p) for b in bursts.values() for p in b)
    for packet in bursts[1] * 2:  # the same vehicle again, before its UART drained: it skips
        radio.offer(packet)
    assert radio.skipped > 0


def _simstate():
    return mavlink.MAVLink_simstate_message(*([0.0] * 9), 0, 0)


class SteadyRadio:
    """True once the radio has kept its buffer at least half free and lost nothing for `seconds`
    on end: a condition to wait for with a deadline, so a loaded machine only makes it come later."""

    def __init__(self, radio, seconds: float) -> None:
        self.radio, self.seconds = radio, seconds
        self.lowest_txbuf = 100
        self._lost = self._lost_now()
        self._since = time.monotonic()

    def _lost_now(self) -> int:
        return self.radio.overflowed + self.radio.skipped

    def __call__(self) -> bool:
        now, txbuf, lost = time.monotonic(), self.radio.txbuf, self._lost_now()
        self.lowest_txbuf = min(self.lowest_txbuf, txbuf)
        if txbuf < 50 or lost != self._lost:
            self._lost, self._since = lost, now
        return now - self._since >= self.seconds


async def _radio_run(port: int, station_baud: int, phases):
    """apm25 behind a simulated 57600 radio; the station told the link runs at station_baud.
    phases(station, radio) waits for what the test expects, each with its own deadline."""
    async with running_station(f"udpin:127.0.0.1:{port}", estimate=False, baud=station_baud) as station:
        sim = SimVehicle(profile="apm25", script="bench")
        radio = fit_radio(sim, 57600)
        task = asyncio.create_task(sim.run(f"udpout:127.0.0.1:{port}"))
        try:
            await wait_for(lambda: station.radio.present, 30, "the radio's RADIO_STATUS")
            await phases(station, radio)
            snapshot = station.publish()
            app = create_app(station, token="t", bound_host="127.0.0.1")
            transport = httpx.ASGITransport(app=app, client=("127.0.0.1", 5000))
            async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as client:
                api = (await client.get("/api/status")).json()["radio"]  # what the page's radio table shows
        finally:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
    return snapshot, radio, api


def test_station_settles_on_rates_the_57600_radio_carries(udp_port):
    async def settles(station, radio):
        # once settled the link carries it all: 10 s with nothing skipped or overflowed, buffer never full
        await wait_for(SteadyRadio(radio, 10.0), 90, "10 s of the radio losing nothing, buffer half free")

    snapshot, radio, api = asyncio.run(_radio_run(udp_port, 57600, settles))
    r = snapshot.radio
    print("\n" + format_report(snapshot).split("\nrecording")[0])
    imu = r.streams["RAW_IMU"]
    assert r.present and r.status is not None and 0 < r.status.rssi <= 255
    assert 5 < imu.predicted_hz < 50 and imu.requested_hz < 50  # predicted to fit, not the wanted 50 Hz
    assert imu.achieved_hz > 0.6 * imu.requested_hz  # (not tighter: a loaded machine slows the vehicle's clock)
    assert r.used_bps < radio.capacity_bps
    assert "RADIO_STATUS" not in r.streams and "predicted" in format_report(snapshot)
    row = api["streams"]["RAW_IMU"]
    assert api["present"] and row["predicted_hz"] == imu.predicted_hz and row["requested_hz"] == imu.requested_hz
    assert 0 < row["achieved_hz"] and 0 <= api["status"]["txbuf"] <= 100


def test_station_backs_off_when_the_radio_buffer_fills(udp_port):
    # told the link is 230400 baud, the station first asks for everything; the 57600 radio's buffer fills
    async def backs_off(station, radio):
        await wait_for(lambda: radio.txbuf < 50, 30, "the radio's buffer filling past half")
        await wait_for(lambda: station.radio.scale < 1.0, 30, "the station lowering its requests")
        # and the buffer recovers: 6 s on end with nothing lost and the buffer at least half free
        await wait_for(SteadyRadio(radio, 6.0), 90, "the radio's buffer recovering")

    snapshot, radio, _ = asyncio.run(_radio_run(udp_port, 230400, backs_off))
    r = snapshot.radio
    print(f"\n{r.choice}; RAW_IMU requested {r.streams['RAW_IMU'].requested_hz}")
    assert r.scale < 1.0 and r.streams["RAW_IMU"].requested_hz < 50  # the station lowered its requests


def test_streams_go_back_to_as_wanted_once_the_radio_is_gone(udp_port):
    """A radio heard for a while, then gone (unplugged, or a stray RADIO_STATUS: the fuzz test's
    left the pixhawk sim at 5 Hz for good) must not cap the streams for the rest of the session:
    once none has come for STATUS_TIMEOUT the station asks for the wanted rates again, and the
    vehicle sends them."""

    async def scenario() -> tuple[float, str]:
        async with (
            running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk") as sim,
            running_station(f"udpin:127.0.0.1:{udp_port}", estimate=False) as station,
        ):

            def raw_imu_hz() -> tuple[float | None, float | None]:
                return station.streams.requested.get("RAW_IMU"), sim.stream_rates().get("RAW_IMU")

            def capped() -> bool:
                return 5.0 < (raw_imu_hz()[1] or 0.0) < 50.0

            await wait_for(lambda: raw_imu_hz() == (50.0, 50.0), 30, "RAW_IMU requested and sent at 50 Hz")
            await radio_status_until(udp_port, capped, 30, "RAW_IMU capped to the 57600 budget")
            capped_hz = raw_imu_hz()[1] or 0.0
            await wait_for(lambda: raw_imu_hz() == (50.0, 50.0), 30, "RAW_IMU at 50 Hz again")
            return capped_hz, station.radio.choice

    capped_hz, choice = asyncio.run(scenario())
    assert 5.0 < capped_hz < 50.0  # the radio's budget did apply while it was there
    assert choice.startswith("radio gone")


def test_a_radio_status_from_no_radio_component_caps_nothing(udp_port):
    """RADIO_STATUS with a full buffer from the vehicle's own ids and from another ground station:
    no radio of this link (a radio reports as component 68), so no radio is found, each sender is
    named once in the event log and every packet counted; the SiK radio's own, after them, is
    taken at once."""

    async def scenario():
        async with (
            running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk") as sim,
            running_station(f"udpin:127.0.0.1:{udp_port}", estimate=False) as station,
        ):
            await wait_for(lambda: sim.stream_rates().get("RAW_IMU") == 50.0, 30, "RAW_IMU sent at 50 Hz")
            full = mavlink.MAVLink_radio_status_message(200, 200, 0, 20, 20, 0, 0)  # txbuf 0 % free
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
                for k in range(10):  # the radio reads at most 20 waiting
                    ids = (1, 1) if k % 2 else (255, 190)
                    sender.sendto(Encoder(*ids).encode(full), ("127.0.0.1", udp_port))
                sender.sendto(Encoder(51, 68).encode(full), ("127.0.0.1", udp_port))  # then the radio's
                await wait_for(lambda: station.radio.present, 30, "a RADIO_STATUS taken")
            radio_events = [e.data for e in station.events.recent if e.kind == "radio"]
            return radio_events, station.publish().radio

    radio_events, snap = asyncio.run(scenario())
    # each foreign sender named once, and only the radio's own packet found a radio
    said = [e.get("ignored", e.get("choice")) for e in radio_events]
    assert sorted(said[:2]) == [
        "RADIO_STATUS from system 1 component 1: no radio (a radio reports as component 68)",
        "RADIO_STATUS from system 255 component 190: no radio (a radio reports as component 68)",
    ]
    assert said[2] == "radio found: requesting the rates predicted to fit"  # (a back-off may follow)
    assert snap is not None and snap.ignored_status == 10


async def radio_status_until(port: int, done, timeout: float, what: str) -> None:
    """A SiK radio's RADIO_STATUS (its ids, its buffer all free) twice a second, as long as
    `done()` is false, then none: a radio unplugged once the test saw what it waited for."""
    deadline = time.monotonic() + timeout
    status = Encoder(51, 68).encode(mavlink.MAVLink_radio_status_message(200, 200, 100, 20, 20, 0, 0))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
        while not done():
            assert time.monotonic() < deadline, f"timed out after {timeout} s waiting for {what}"
            sender.sendto(status, ("127.0.0.1", port))
            await asyncio.sleep(0.5)


def test_two_vehicles_behind_one_radio_share_its_budget(udp_port):
    """Two APM 2.5s behind one SiK radio (a multipoint network): each vehicle's plan takes half of
    the radio's budget, so together they fit it, and the radio settles with nothing lost."""
    address = f"udpin:127.0.0.1:{udp_port}"

    async def scenario():
        fleet = Fleet(StationConfig(connect=address, estimate=False, baud=57600), [address])
        sims = [SimVehicle(profile="apm25", sysid=sysid, script="bench") for sysid in (1, 2)]
        radio = fit_radio(sims[0], 57600)
        assert fit_radio(sims[1], radio=radio) is radio
        await fleet.start()
        tasks = [asyncio.create_task(sim.run(f"udpout:127.0.0.1:{udp_port}")) for sim in sims]
        try:
            await wait_for(
                lambda: len(fleet.vehicles()) == 2 and all(e.station.radio.present for e in fleet.vehicles()),
                30,
                "both vehicles and the radio heard",
            )
            await wait_for(SteadyRadio(radio, 10.0), 120, "10 s of the shared radio losing nothing")
            return [e.station.publish().radio for e in fleet.vehicles()], radio
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            await fleet.stop()

    snapshots, radio = asyncio.run(scenario())
    wanted = {k: v for k, v in StreamPlan().for_autopilot("ArduPilot").items() if k not in ("SCALED_IMU2", "AHRS2")}
    alone = predict(wanted, 1, 0.8 * link_capacity(57600), background_bps=300, groups=STREAM_GROUPS)
    for snap in snapshots:
        print(f"\n{snap.choice}; RAW_IMU {snap.streams['RAW_IMU'].predicted_hz} Hz (alone {alone.rates['RAW_IMU']})")
        assert snap.shared_by == 2 and snap.budget_bps == pytest.approx(0.4 * radio.capacity_bps, abs=0.1)
        assert 0 < snap.streams["RAW_IMU"].predicted_hz < alone.rates["RAW_IMU"]  # each plans on its half
    assert sum(snap.used_bps for snap in snapshots) < radio.capacity_bps


def test_log_download_over_the_57600_radio_completes(tmp_path, udp_port):
    async def scenario():
        async with running_station(f"udpin:127.0.0.1:{udp_port}", request_streams=False, estimate=False) as station:
            sim = SimVehicle(profile="apm25", script="bench")
            fly_flight_logs(sim, [4.0])
            radio = fit_radio(sim, 57600)
            task = asyncio.create_task(sim.run(f"udpout:127.0.0.1:{udp_port}"))
            try:
                assert await station.link.wait_connected(30)
                downloader = LogDownloader(station.link)
                entry = (await downloader.list_logs(30))[0]
                path = await asyncio.wait_for(downloader.download(entry, tmp_path), 180)
            finally:
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)
        return path, sim, radio, downloader.progress

    path, sim, radio, progress = asyncio.run(scenario())
    print(
        f"\n{progress.size} B over the 57600 radio at {progress.rate_bps:.0f} B/s, {progress.re_requests} re-requests"
    )
    assert path.read_bytes() == sim.logs.finished[0]
    assert 0 < progress.rate_bps <= radio.capacity_bps  # the radio's pace, reported
