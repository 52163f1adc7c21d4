"""Onboard log download: the simulator's DataFlash logs and ArduPilot's log protocol, the
ground side's re-requests and resume over real UDP sockets, and the downloaded logs through
the estimators."""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import subprocess
import sys

import httpx
import pytest
from live import other_system, running_sim, running_station, stop_process, wait_for
from pymavlink.DFReader import DFReader_binary

from gcs.mavlink.dialect import Encoder, mavlink
from gcs.mavlink.logtransfer import LogEntry, LogTransfer
from gcs.runtime.logdownload import LogDownloader, LogDownloadError, PartialLog
from gcs.runtime.replay import ReplaySession
from gcs.server.app import create_app
from gcs.server.deps import TOKEN_HEADER
from gcs.sessions.sources import open_source
from gcs.sim import SimVehicle
from gcs.sim.logserver import LOG_DATA_LEN, SEND_LOOP_HZ, SITL_SENDS_PER_LOOP
from gcs.sim.recording import fly_flight_logs

GCS = Encoder(255, 190, mavlink1=True)


def _parse(packets: list[bytes]) -> list:
    parser = mavlink.MAVLink(None)
    return [m for p in packets for m in parser.parse_buffer(p) or []]


def _gcs_heartbeat() -> bytes:
    return GCS.encode(
        mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 4, 3)
    )


def test_sim_serves_logs_with_ardupilots_limits():
    sim = SimVehicle(profile="apm25", script="bench")
    fly_flight_logs(sim, [5.0])
    sim.handle_bytes(_gcs_heartbeat())
    sim.handle_bytes(GCS.encode(mavlink.MAVLink_log_request_list_message(1, 1, 0, 0xFFFF)))
    entries = [m for m in _parse(sim.advance(0.5)) if m.get_type() == "LOG_ENTRY"]
    assert [(e.id, e.num_logs, e.last_log_num) for e in entries] == [(1, 2, 2), (2, 2, 2)]
    assert entries[0].size == len(sim.logs.finished[0])  # the flight flown before boot
    assert entries[1].size == len(sim.logs.finished[1])  # this flight's log, closed by the listing

    sim.handle_bytes(GCS.encode(mavlink.MAVLink_log_request_data_message(1, 1, 1, 0, 0xFFFFFFFF)))
    sim.handle_bytes(GCS.encode(mavlink.MAVLink_log_request_data_message(1, 1, 1, 900, 90)))  # ignored: sending
    first_loop = [m for m in _parse(sim.advance(sim.t + 1.5 / SEND_LOOP_HZ)) if m.get_type() == "LOG_DATA"]
    assert len(first_loop) == SITL_SENDS_PER_LOOP  # one send loop's worth
    assert [m.ofs for m in first_loop] == [k * LOG_DATA_LEN for k in range(SITL_SENDS_PER_LOOP)]
    assert all(m.count == LOG_DATA_LEN for m in first_loop)

    sim.autopilot.armed = True  # nothing is served while armed, and the vehicle says why
    sim.handle_bytes(GCS.encode(mavlink.MAVLink_log_request_list_message(1, 1, 0, 0xFFFF)))
    texts = [m.text for m in _parse(sim.advance(sim.t + 0.1)) if m.get_type() == "STATUSTEXT"]
    assert texts == ["Disarm for log download"]


@pytest.mark.parametrize(("profile", "time_field"), [("apm25", "TimeMS"), ("pixhawk", "TimeUS")])
def test_flight_log_is_a_dataflash_log_of_the_profiles_generation(tmp_path, profile, time_field):
    sim = SimVehicle(profile=profile, script="bench")
    sim.advance(3.0)
    sim.logs.close_current()
    path = tmp_path / "flight.bin"
    path.write_bytes(sim.logs.finished[0])
    log = DFReader_binary(str(path))
    counts: dict[str, int] = {}
    while (r := log.recv_match(type=["IMU", "ATT", "MAG", "GPS", "SIM", "PARM"])) is not None:
        counts[r.get_type()] = counts.get(r.get_type(), 0) + 1
        if r.get_type() == "IMU":
            assert hasattr(r, time_field)
    assert counts["IMU"] == pytest.approx(3.0 * sim.profile.loop_hz, abs=2)  # the full loop rate
    assert counts["ATT"] == pytest.approx(150, abs=2) and counts["SIM"] == counts["ATT"]
    assert counts["GPS"] == pytest.approx(15, abs=1) and counts["MAG"] == pytest.approx(30, abs=1)
    assert counts["PARM"] == len(sim.params)


def test_transfer_asks_again_for_what_was_lost():
    entry = LogEntry(1, 1, 1, 0, 1000)  # 12 chunks, the last one 10 bytes
    transfer = LogTransfer(entry, idle_timeout=0.5)
    assert transfer.next_request(0.0).count == 0xFFFFFFFF
    for k in range(12):
        if k not in (3, 4, 11):
            n = min(90, 1000 - 90 * k)
            transfer.on_data(1, 90 * k, n, bytes([k]) * n, 0.01)
    assert transfer.next_request(0.1) is None  # the request may still be answered
    again = transfer.next_request(0.6)  # silent past the wait: the last chunk was lost
    assert (again.ofs, again.count) == (270, 1000 - 270)  # gaps 3-4 and 11 asked as one run
    assert transfer.missing_runs() == [(3, 5), (11, 12)]


@contextlib.asynccontextmanager
async def log_vehicle(address: str, profile: str, flight_s: float, log_drop: float = 0.0, **sim_options):
    """A simulated vehicle with one earlier flight's log (log 1); the station asks for logs only
    later, so the flight is flown once the vehicle serves."""
    async with running_sim(address, profile=profile, script="bench", **sim_options) as sim:
        fly_flight_logs(sim, [flight_s])
        sim.log_server.drop = log_drop
        yield sim


def test_download_over_udp_with_10_percent_loss_is_byte_identical(tmp_path, udp_port):
    asyncio.run(_download_over_udp_with_10_percent_loss_is_byte_identical(tmp_path, udp_port))


async def _download_over_udp_with_10_percent_loss_is_byte_identical(tmp_path, udp_port):
    async with (
        running_station(f"udpin:127.0.0.1:{udp_port}", request_streams=False, estimate=False) as station,
        log_vehicle(f"udpout:127.0.0.1:{udp_port}", "apm25", 20.0, log_drop=0.1) as sim,
    ):
        assert await station.link.wait_connected(30)
        downloader = LogDownloader(station.link)
        entries = await downloader.list_logs(30)
        path = await asyncio.wait_for(downloader.download(entries[0], tmp_path), 120)
    assert path.read_bytes() == sim.logs.finished[0]
    assert sim.log_server.dropped > 0.05 * sim.log_server.sent  # the loss really happened
    progress = downloader.progress
    assert progress.state == "done" and progress.re_requests > 0 and progress.rate_bps > 0
    assert not list(tmp_path.glob("*.partial*"))  # the partial files are gone once the log is whole
    print(f"\n{entries[0].size} B, {progress.rate_bps:.0f} B/s, {progress.re_requests} re-requests")


def test_download_resumes_after_a_link_drop(tmp_path, udp_port):
    asyncio.run(_download_resumes_after_a_link_drop(tmp_path, udp_port))


async def _download_resumes_after_a_link_drop(tmp_path, udp_port):
    address = f"udpout:127.0.0.1:{udp_port}"
    async with running_station(f"udpin:127.0.0.1:{udp_port}", request_streams=False, estimate=False) as station:
        downloader = LogDownloader(station.link, stall_timeout=1.5, save_interval=0.2)
        async with log_vehicle(address, "apm25", 20.0) as sim:
            sim.log_server.sends_per_loop = 4  # slow enough to cut it halfway
            assert await station.link.wait_connected(30)
            entry = (await downloader.list_logs(30))[0]
            task = asyncio.create_task(downloader.download(entry, tmp_path))
            await wait_for(lambda: downloader.progress.bytes_received > entry.size // 3, 60, "a third of the log")
        with pytest.raises(LogDownloadError, match="run again to resume"):  # the vehicle went away
            await asyncio.wait_for(task, 30)
        kept = downloader.progress.bytes_received
        assert list(tmp_path.glob("*.partial")) and 0 < kept < entry.size
        async with log_vehicle(address, "apm25", 20.0) as sim:  # back: the same logs
            path = await asyncio.wait_for(downloader.download(entry, tmp_path), 120)
    assert path.read_bytes() == sim.logs.finished[0]
    assert downloader.progress.resumed_bytes >= kept - 20 * LOG_DATA_LEN  # saved at most 0.2 s before


@pytest.mark.parametrize("profile", ["apm25", "pixhawk"])
def test_downloaded_log_replays_through_the_estimators(tmp_path, udp_port, profile):
    asyncio.run(_downloaded_log_replays_through_the_estimators(tmp_path, udp_port, profile))


async def _downloaded_log_replays_through_the_estimators(tmp_path, udp_port, profile):
    async with (
        running_station(f"udpin:127.0.0.1:{udp_port}", request_streams=False, estimate=False) as station,
        log_vehicle(f"udpout:127.0.0.1:{udp_port}", profile, 20.0) as sim,
    ):
        assert await station.link.wait_connected(30)
        downloader = LogDownloader(station.link)
        entry = (await downloader.list_logs(30))[0]
        path = await asyncio.wait_for(downloader.download(entry, tmp_path), 120)
    assert path.read_bytes() == sim.logs.finished[0]
    session = ReplaySession(open_source(path), 0, ["ekf"], {})
    session.run_to_end()
    assert session.pipeline.imu_samples == pytest.approx(20 * sim.profile.loop_hz, abs=2)  # full rate
    truth = session.pipeline.comparisons["ekf"].summary()["references"]["truth"]
    rms = truth["session"]["rms"]
    print(f"\n{profile}: ekf vs SIM truth RMS roll/pitch/yaw {rms}")
    assert truth["n"] > 500 and max(rms) < 3.0  # degrees, the live-simulator bounds


def test_dashboard_download_lands_in_the_replay_folder(tmp_path, udp_port):
    asyncio.run(_dashboard_download(tmp_path, udp_port))


async def _dashboard_download(tmp_path, udp_port):
    token = "s3cret-token"
    async with (
        running_station(
            f"udpin:127.0.0.1:{udp_port}",
            request_streams=False,
            estimate=False,
            sessions_dir=str(tmp_path),
            record=True,
        ) as station,
        log_vehicle(f"udpout:127.0.0.1:{udp_port}", "apm25", 10.0) as sim,
    ):
        assert await station.link.wait_connected(30)
        app = create_app(station, token=token, bound_host="127.0.0.1")
        transport = httpx.ASGITransport(app=app, client=("127.0.0.1", 5000))
        async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as client:
            refused = await client.post("/api/onboard-logs/download", json={"log": 1})
            assert refused.status_code in (401, 403)
            started = await client.post("/api/onboard-logs/download", json={"log": 1}, headers={TOKEN_HEADER: token})
            assert started.status_code == 202 and started.json()["download"] == "started"

            async def state():
                return (await client.get("/api/onboard-logs")).json()

            deadline = asyncio.get_running_loop().time() + 120
            while (body := await state())["progress"]["state"] not in ("done", "failed"):
                assert asyncio.get_running_loop().time() < deadline, body
                await asyncio.sleep(0.2)
            assert body["progress"]["state"] == "done", body
            assert body["logs"][0]["size"] == len(sim.logs.finished[0])
            names = [log["name"] for log in (await client.get("/api/logs")).json()]  # the replay sources
    path = tmp_path / body["progress"]["path"].split("/")[-1]
    assert path.name in names and path.read_bytes() == sim.logs.finished[0]


def test_gcs_logs_download_latest_from_gcs_sim(tmp_path, udp_port):
    vehicle_dir, out = tmp_path / "vehicle", tmp_path / "out"
    sim = [sys.executable, "-m", "gcs", "sim", "--profile", "pixhawk", "--flight-log", "4"]
    proc = subprocess.Popen(
        [*sim, "--log-dir", str(vehicle_dir), "--link", f"udpout:127.0.0.1:{udp_port}"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        command = ["logs", "download", "latest", "--connect", f"udpin:127.0.0.1:{udp_port}", "--out", str(out)]
        done = subprocess.run(
            [sys.executable, "-m", "gcs", *command], capture_output=True, text=True, timeout=120, check=False
        )
    finally:
        stop_process(proc)
    assert done.returncode == 0, done.stderr
    assert "log 2:" in done.stdout and "kB/s" in done.stdout and "gcs replay" in done.stdout
    (downloaded,) = out.glob("log2-*.bin")
    assert downloaded.read_bytes() == (vehicle_dir / "00000002.BIN").read_bytes()  # the flight flown live


def test_gcs_logs_download_from_a_signing_vehicle_with_its_key(tmp_path, udp_port):
    """`gcs logs` takes --signing-key as every link command does: a signing vehicle refuses
    unsigned requests, and the station refuses its signed packets without the key."""

    async def download() -> tuple[int | None, str, bytes]:
        key = hashlib.sha256(b"flight test 13").digest()
        async with log_vehicle(f"udpout:127.0.0.1:{udp_port}", "pixhawk", 4.0, signing_key=key) as sim:
            proc = await asyncio.create_subprocess_exec(
                sys.executable, "-m", "gcs", "logs", "download", "1", "--connect", f"udpin:127.0.0.1:{udp_port}",
                "--out", str(tmp_path), "--signing-key", "flight test 13",
                stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
            )  # fmt: skip
            out, err = await asyncio.wait_for(proc.communicate(), 120)
            return proc.returncode, out.decode() + err.decode(), sim.logs.finished[0]

    rc, output, log = asyncio.run(download())
    assert rc == 0, output
    (downloaded,) = tmp_path.glob("log1-*.bin")
    assert downloaded.read_bytes() == log


def test_gcs_logs_takes_baud_auto_and_heartbeat_timeout_as_every_link_command(tmp_path):
    """`gcs logs` shares the link options of the other link commands (gcs.commands.options): on a
    serial port (a pty the simulator serves) --baud auto finds the rate and the logs are listed;
    a --heartbeat-timeout of 0 is refused in the same one line. Both were refused before ("--baud
    'auto': give a rate such as 57600", "unrecognized arguments: --heartbeat-timeout")."""
    path = tmp_path / "ttyUSB-sim"
    logs = [sys.executable, "-m", "gcs", "logs", "list", "--connect", str(path)]

    async def listing() -> tuple[int | None, str, int]:
        async with log_vehicle(f"pty:{path}", "apm25", 4.0) as sim:
            proc = await asyncio.create_subprocess_exec(
                *logs, "--baud", "auto", "--heartbeat-timeout", "5", "--timeout", "30",
                stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
            )  # fmt: skip
            out, err = await asyncio.wait_for(proc.communicate(), 120)
            return proc.returncode, out.decode() + err.decode(), len(sim.logs.finished[0])

    rc, output, size = asyncio.run(listing())
    assert rc == 0, output
    assert output.splitlines()[1].split()[:2] == ["1", str(size)], output
    refused = subprocess.run([*logs, "--heartbeat-timeout", "0"], capture_output=True, text=True, timeout=60)
    assert refused.returncode == 2 and refused.stderr == "gcs logs list: --heartbeat-timeout 0.0: give seconds > 0\n"


def test_partial_download_resumes_only_the_same_log(tmp_path):
    entry = LogEntry(3, 3, 3, 1_767_225_600, 500)
    transfer = LogTransfer(entry)
    transfer.on_data(3, 90, 90, b"x" * 90, 0.0)
    partial = PartialLog(tmp_path / "log3.bin", entry)
    partial.save(bytes(transfer.data), bytes(transfer.have))
    resumed = partial.load(0.5)
    assert resumed.bytes_received == 90 and resumed.data[90:180] == b"x" * 90
    other = LogEntry(3, 3, 3, 1_767_225_600, 501)  # same id, another size: another log (erased, new flight)
    assert PartialLog(tmp_path / "log3.bin", other).load(0.5).bytes_received == 0
    (tmp_path / "log3.bin.partial.json").write_text("{not json")  # damaged: start afresh, no traceback
    assert partial.load(0.5).bytes_received == 0


def test_a_download_never_replaces_another_log_of_the_same_name(tmp_path, udp_port, monkeypatch):
    """A vehicle without a clock names its logs by id alone, and after its logs are erased log 1 is
    another flight: `gcs logs download 1` replaced the earlier flight's log1.bin. It is kept and
    the new log goes beside it (and the same log again is not written a second time)."""
    earlier = b"\xa3\x95 yesterday's flight" * 100
    (tmp_path / "log1.bin").write_bytes(earlier)

    async def download() -> tuple[list[str], bytes]:
        async with log_vehicle(f"udpout:127.0.0.1:{udp_port}", "apm25", 3.0) as sim:
            outputs = []
            for _ in range(2):
                proc = await asyncio.create_subprocess_exec(
                    sys.executable, "-m", "gcs", "logs", "download", "1", "--connect", f"udpin:127.0.0.1:{udp_port}",
                    "--out", str(tmp_path), stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
                )  # fmt: skip
                out, err = await asyncio.wait_for(proc.communicate(), 120)
                assert proc.returncode == 0, err.decode()
                outputs.append(out.decode())
            return outputs, sim.logs.finished[0]

    monkeypatch.setattr("gcs.sim.logserver.LOG_TIME_UTC", 0)  # a vehicle without the date: no GPS
    outputs, log = asyncio.run(download())
    assert (tmp_path / "log1.bin").read_bytes() == earlier
    assert (tmp_path / "log1-2.bin").read_bytes() == log
    assert all(f"-> {tmp_path / 'log1-2.bin'}\n" in out for out in outputs), outputs
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log1-2.bin", "log1.bin"]


def test_log_data_from_another_system_is_not_written_into_the_vehicles_log(tmp_path, udp_port):
    """Another system on the link answers each LOG_REQUEST_DATA the station sends, at once, with
    zeros for the asked bytes, and each listing with a log of its own: the log in the recording
    folder is still the vehicle's, byte for byte."""

    def forge(msg, mav):
        if msg.get_type() == "LOG_REQUEST_DATA":
            count = min(msg.count, LOG_DATA_LEN)
            return [mav.log_data_encode(msg.id, msg.ofs, count, bytes(LOG_DATA_LEN))]
        if msg.get_type() == "LOG_REQUEST_LIST":
            return [mav.log_entry_encode(7, 1, 7, 0, 123)]
        return []

    async def scenario():
        async with running_station(f"udpin:127.0.0.1:{udp_port}", request_streams=False, estimate=False) as station:
            with other_system(udp_port, forge) as forged:
                await wait_for(lambda: station.link.stats.framing.packets > 0, 10, "the other system heard")
                async with log_vehicle(f"udpout:127.0.0.1:{udp_port}", "apm25", 5.0) as sim:
                    assert await station.link.wait_connected(30)
                    downloader = LogDownloader(station.link)
                    entries = await downloader.list_logs(30)
                    path = await asyncio.wait_for(downloader.download(entries[0], tmp_path), 120)
                    return entries, path.read_bytes(), sim.logs.finished[0], len(forged)

    entries, downloaded, flown, forged = asyncio.run(scenario())
    assert forged  # the other system was asked and answered
    assert 7 not in [e.id for e in entries]  # the other system's log is not listed as the vehicle's
    assert downloaded == flown
