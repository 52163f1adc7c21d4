"""Issue 13 item 1 acceptance: several vehicles on one station. Two simulators (sysid 1 apm25,
sysid 2 pixhawk, each a `gcs sim` process) send to one UDP port and a third (sysid 3 px4) to a
second; a ground station (sysid 255) and companion computers send heartbeats on the first link
too. The station lists exactly the three vehicles (on the real uvicorn server and in
`gcs status`), each with its own estimates, parameters, recording, and a gain change on one
reaches no other."""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Awaitable, Callable
from pathlib import Path

import httpx
import numpy as np
import pytest
from conftest import free_port
from live import stop_process, wait_for
from test_estimation_live import errors_after

import gcs
from gcs.mavlink.dialect import Encoder, mavlink
from gcs.mavlink.framing import MavlinkDecoder
from gcs.mavlink.tlog import read_tlog_records
from gcs.runtime.fleet import Fleet
from gcs.runtime.replay import ReplaySession
from gcs.runtime.station import StationConfig
from gcs.server.dashboard import DashboardServer
from gcs.sessions import layout
from gcs.sessions.sources import open_source
from gcs.sim import SimVehicle

#: (sysid, profile, which link) of the simulated vehicles
VEHICLES = ((1, "apm25", 0), (2, "pixhawk", 0), (3, "px4", 1))
#: each vehicle's roll-rate gain (the tuning profile's detect parameter)
ROLL_RATE_P = {1: "RATE_RLL_P", 2: "ATC_RAT_RLL_P", 3: "MC_ROLLRATE_P"}


@contextlib.contextmanager
def sim_processes(ports: list[int]):
    procs = []
    try:
        for sysid, profile, link in VEHICLES:
            command = [sys.executable, "-m", "gcs", "sim", "--profile", profile, "--script", "quad"]
            command += ["--sysid", str(sysid), "--link", f"udpout:127.0.0.1:{ports[link]}"]
            procs.append(subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        yield procs
    finally:
        for proc in procs:
            stop_process(proc)


async def not_vehicles(port: int, stop: asyncio.Event) -> None:
    """Heartbeats that are no vehicle's, twice a second: another ground station (255/190), a
    companion computer on vehicle 1 (1/191) and one with a system id of its own (42/191)."""
    senders = [
        (Encoder(255, 190), mavlink.MAV_TYPE_GCS),
        (Encoder(1, 191), mavlink.MAV_TYPE_ONBOARD_CONTROLLER),
        (Encoder(42, 191), mavlink.MAV_TYPE_ONBOARD_CONTROLLER),
    ]
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        while not stop.is_set():
            for encoder, kind in senders:
                beat = mavlink.MAVLink_heartbeat_message(kind, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 4, 3)
                sock.sendto(encoder.encode(beat), ("127.0.0.1", port))
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), 0.5)
    finally:
        sock.close()


def truth_params(sysid: int, profile: str) -> dict[str, float]:
    """The parameter table the simulator process serves (the same for every seed)."""
    return SimVehicle(profile=profile, sysid=sysid).params.as_dict()


def test_three_vehicles_on_two_links(tmp_path: Path) -> None:
    ports = [free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_DGRAM)]
    config = StationConfig(connect=f"udpin:127.0.0.1:{ports[0]}", sessions_dir=str(tmp_path), record=True)

    async def scenario():
        fleet = Fleet(config, [f"udpin:127.0.0.1:{port}" for port in ports])
        points: dict[int, list] = {sysid: [] for sysid, _, _ in VEHICLES}
        server = DashboardServer(fleet.first, port=0, viser=False, fleet=fleet)
        fleet.vehicle_added.connect(lambda e: e.station.points.connect(points[e.sysid].extend))
        await fleet.start()
        await server.start()
        stop = asyncio.Event()
        others = asyncio.create_task(not_vehicles(ports[0], stop))
        base = f"http://127.0.0.1:{server.port}"
        try:
            with sim_processes(ports):
                async with httpx.AsyncClient(base_url=base, headers=server.auth_headers, timeout=30) as api:
                    await wait_for(lambda: len(fleet.vehicles()) == 3, 60, "three vehicles")
                    await wait_for(
                        lambda: all(p and p[-1].t > 16.0 for p in points.values()), 90, "16 s of each vehicle"
                    )
                    listed = (await api.get("/api/vehicles")).json()
                    downloads = [e.station.params.download(timeout=90) for e in fleet.vehicles()]
                    tables = dict(zip([e.sysid for e in fleet.vehicles()], await asyncio.gather(*downloads)))
                    status2 = (await api.get("/api/vehicles/2/status")).json()
                    first_status = (await api.get("/api/status")).json()
                    missing = await api.get("/api/vehicles/42/status")
                    history3 = (await api.get("/api/vehicles/3/history?seconds=5")).json()

                    # a gain change on vehicle 2, through its URLs: an estimator gain and a vehicle parameter
                    before = {e.sysid: e.station.estimator("dcm").gains.values.copy() for e in fleet.vehicles()}
                    gain = next(iter(before[2]))
                    gains2 = (await api.get("/api/vehicles/2/estimators/dcm")).json()["gains"]
                    info = next(g for g in gains2 if g["name"] == gain)
                    new_gain = info["min"] if info["value"] != info["min"] else info["max"]
                    async with httpx.AsyncClient(base_url=base, timeout=30) as anonymous:  # no token
                        refused = await anonymous.put(
                            f"/api/vehicles/2/estimators/dcm/gains/{gain}", json={"value": new_gain}
                        )
                    put = await api.put(f"/api/vehicles/2/estimators/dcm/gains/{gain}", json={"value": new_gain})
                    after = {e.sysid: e.station.estimator("dcm").gains.values.copy() for e in fleet.vehicles()}
                    tuned = await api.put("/api/vehicles/2/tuning/ATC_RAT_RLL_P", json={"value": 0.15})
                    reread = {
                        e.sysid: (await e.station.params.read(ROLL_RATE_P[e.sysid])).value for e in fleet.vehicles()
                    }
                    folders = {e.sysid: e.station.recording().session.folder for e in fleet.vehicles()}
        finally:
            stop.set()
            await others
            await server.stop()
            await fleet.stop()
        sysids = [e.sysid for e in fleet.vehicles()]
        return dict(
            sysids=sysids,
            listed=listed,
            points=points,
            tables=tables,
            status2=status2,
            first_status=first_status,
            missing=missing.status_code,
            history3=history3,
            gain=gain,
            new_gain=new_gain,
            put=put.status_code,
            refused=refused.status_code,
            before=before,
            after=after,
            tuned=(tuned.status_code, tuned.json()),
            reread=reread,
            folders=folders,
        )

    r = asyncio.run(scenario())

    # three vehicles, no GCS (255) and no companion (1/191, 42/191) among them
    assert sorted(r["sysids"]) == [1, 2, 3]
    assert sorted(v["sysid"] for v in r["listed"]) == [1, 2, 3]
    by_sysid = {v["sysid"]: v for v in r["listed"]}
    assert by_sysid[3]["link"] == f"udpin:127.0.0.1:{ports[1]}" and by_sysid[1]["link"] == by_sysid[2]["link"]
    assert [by_sysid[n]["autopilot"] for n in (1, 2, 3)] == ["ArduPilot", "ArduPilot", "PX4"]
    assert r["status2"]["vehicle"]["sysid"] == 2 and r["status2"]["vehicle"]["compid"] == 1
    # three senders on one port, and a companion on sysid 1 (compid 191): no two senders on one id
    assert not r["status2"]["vehicle"]["two_senders"] and not r["first_status"]["vehicle"]["two_senders"]
    assert r["first_status"]["vehicle"]["sysid"] == r["sysids"][0]
    assert r["missing"] == 404
    assert {"dcm", "truth"} <= set(r["history3"]["points"])

    # each its own estimates, within the live-simulator bounds (tests/test_estimation_live.py)
    for sysid, points in r["points"].items():
        for name, (roll, pitch, yaw) in errors_after(points, 10.0, 16.0).items():
            assert roll < 3.0 and pitch < 3.0, f"vehicle {sysid} {name}: roll/pitch {roll:.2f}/{pitch:.2f} deg"
            assert yaw < 10.0, f"vehicle {sysid} {name}: yaw {yaw:.2f} deg"

    # each its own parameters, downloaded exactly (before the tuning write below)
    for sysid, profile, _ in VEHICLES:
        truth = truth_params(sysid, profile)
        got = {name: p.value for name, p in r["tables"][sysid].items()}
        assert got == truth, f"vehicle {sysid}: {len(set(got) ^ set(truth))} names differ"
    assert r["tables"][2]["SYSID_THISMAV"].value == 2 and r["tables"][3]["MAV_SYS_ID"].value == 3

    # the gain change on vehicle 2 touched no other vehicle
    assert r["refused"] == 401 and r["put"] == 200  # a vehicle's URL takes the token as the plain one does
    assert r["after"][2][r["gain"]] == r["new_gain"] != r["before"][2][r["gain"]]
    assert r["after"][1] == r["before"][1] and r["after"][3] == r["before"][3]
    status, body = r["tuned"]
    assert status == 200 and body["new"] == r["reread"][2] == pytest.approx(0.15, rel=1e-6)  # a float32
    assert r["reread"][1] == truth_params(1, "apm25")["RATE_RLL_P"]
    assert r["reread"][3] == truth_params(3, "px4")["MC_ROLLRATE_P"]

    # each its own recording
    folders = r["folders"]
    assert len(set(folders.values())) == 3 and all(f.parent == tmp_path for f in folders.values())
    for sysid, folder in folders.items():
        meta = json.loads((folder / "meta.json").read_text())
        assert meta["vehicle"]["label"].endswith(f"-{sysid}")


def test_status_lists_every_vehicle() -> None:
    ports = [free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_DGRAM)]
    command = [sys.executable, "-m", "gcs", "status", "--duration", "8"]
    for port in ports:
        command += ["--connect", f"udpin:127.0.0.1:{port}"]
    status = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        with sim_processes(ports):
            out, err = status.communicate(timeout=120)
    finally:
        if status.poll() is None:
            stop_process(status)
    assert status.returncode == 0, err
    assert out.startswith("vehicles   3\n"), out
    for sysid, _, link in VEHICLES:
        assert f"== vehicle sysid {sysid} ==" in out
        line = next(line for line in out.splitlines() if line.startswith(f"  sysid {sysid} "))
        assert f"on udpin:127.0.0.1:{ports[link]}" in line and "connected" in line


@pytest.mark.timeout(600)
def test_dashboard_vehicle_selector(tmp_path: Path) -> None:
    """Real Chromium: the selector lists both vehicles on one port, and choosing the second
    switches the page's REST and WebSocket URLs to /api/vehicles/2/... (its panel shows its own
    firmware: ArduCopter 4.5.7, not the APM 2.5's 3.2.1). The what-if source picker tells the two
    vehicles' sessions apart (both started in the same second, and were listed by time alone)."""
    from live import CHROMIUM, CHROMIUM_ARGS, POLL_MS
    from playwright.async_api import async_playwright

    port = free_port(socket.SOCK_DGRAM)

    async def scenario() -> tuple[list[str], list[str], str, list[str]]:
        fleet = Fleet(StationConfig(connect=f"udpin:127.0.0.1:{port}", sessions_dir=str(tmp_path), record=True))
        server = DashboardServer(fleet.first, port=0, viser=False, fleet=fleet)
        await fleet.start()
        await server.start()
        urls: list[str] = []
        try:
            with sim_processes([port, free_port(socket.SOCK_DGRAM)]):  # the third one talks to nobody
                await wait_for(lambda: len(fleet.vehicles()) == 2, 60, "two vehicles")
                async with async_playwright() as pw:
                    browser = await pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
                    page = await browser.new_page()
                    page.on("request", lambda request: urls.append(request.url))
                    page.on("websocket", lambda ws: urls.append(ws.url))
                    await page.goto(server.url, timeout=120_000, wait_until="commit")
                    select = "#vehicle-select"
                    await page.wait_for_function(
                        f"!document.querySelector('{select}').hidden "
                        f"&& document.querySelector('{select}').options.length === 2",
                        polling=POLL_MS,
                        timeout=120_000,
                    )
                    options = await page.eval_on_selector_all(f"{select} option", "os => os.map(o => o.value)")
                    await page.select_option(select, "2")
                    await page.wait_for_function("window.gcsVehicle === '2'", polling=POLL_MS, timeout=60_000)
                    await page.wait_for_function(
                        "(document.querySelector('#vehicle-autopilot') || {}).textContent?.includes('4.5.7')",
                        polling=POLL_MS,
                        timeout=120_000,
                    )
                    await page.wait_for_function("window.gcsStats.messages > 0", polling=POLL_MS, timeout=60_000)
                    shown = await page.text_content("#vehicle-autopilot") or ""
                    await page.click("button[data-tab=whatif]")
                    picker = "#whatif-source option"
                    sessions_listed = (
                        f"[...document.querySelectorAll('{picker}')].filter(o => o.text.startsWith('session'))"
                    )
                    await page.wait_for_function(
                        f"{sessions_listed}.length >= 2",
                        polling=POLL_MS,
                        timeout=60_000,
                    )
                    labels = await page.eval_on_selector_all(picker, "os => os.map(o => o.text)")
                    await browser.close()
        finally:
            await server.stop()
            await fleet.stop()
        return options, urls, shown, [label for label in labels if label.startswith("session")]

    options, urls, shown, sessions = asyncio.run(scenario())
    assert len(set(sessions)) == len(sessions) >= 2, sessions
    assert sorted(options) == ["1", "2"]
    assert any(u.endswith("/api/vehicles/2/status") for u in urls)
    assert any(u.endswith("/api/vehicles/2/ws/live") for u in urls)
    assert "3.2.1" not in shown


def test_demo_refuses_two_vehicles_with_one_sysid() -> None:
    command = [sys.executable, "-m", "gcs", "demo", "--vehicles", "apm25:1,pixhawk:1"]
    result = subprocess.run(command, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert result.stderr.strip().endswith("'apm25:1,pixhawk:1': each vehicle needs a system id of its own")


def test_routing_by_link_and_sysid() -> None:
    """The fleet's routing on real packets fed to its link's receive path: vehicles from
    heartbeats only, each vehicle's data on its own bus, a radio's RADIO_STATUS to every vehicle,
    sensor data of a vehicle not yet heard to no other vehicle."""

    def packets(sysid: int, compid: int, *msgs) -> bytes:
        encoder = Encoder(sysid, compid)
        return b"".join(encoder.encode(m) for m in msgs)

    def beat(kind: int, autopilot: int = mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA):
        return mavlink.MAVLink_heartbeat_message(kind, autopilot, 0, 0, 4, 3)

    def imu(k: int):
        return mavlink.MAVLink_raw_imu_message(k * 20_000, 10, -20, -1000, 1, 2, 3, 200, -50, 400)

    async def scenario():
        fleet = Fleet(StationConfig(connect="udpin:127.0.0.1:0", estimate=False))
        buses = {}
        fleet.vehicle_added.connect(lambda e: buses.setdefault(e.sysid, e.station.bus.subscribe("t")))
        feed = fleet.links[0]._on_data
        feed(packets(1, 1, beat(mavlink.MAV_TYPE_QUADROTOR), imu(1)))
        feed(packets(2, 1, imu(1)))  # vehicle 2's data before its first heartbeat
        feed(packets(255, 190, beat(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID)))
        feed(packets(1, 191, beat(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID)))
        feed(packets(2, 1, beat(mavlink.MAV_TYPE_FIXED_WING), imu(2)))
        feed(packets(51, 68, mavlink.MAVLink_radio_status_message(200, 190, 50, 20, 25, 0, 0)))
        got = {sysid: [(m.type, m.sysid, m.compid) for m in sub.drain()] for sysid, sub in buses.items()}
        return [(e.sysid, e.compid) for e in fleet.vehicles()], got

    vehicles, got = asyncio.run(scenario())
    assert vehicles == [(1, 1), (2, 1)]
    assert got[1] == [
        ("HEARTBEAT", 1, 1),
        ("RAW_IMU", 1, 1),
        ("HEARTBEAT", 255, 190),
        ("HEARTBEAT", 1, 191),
        ("RADIO_STATUS", 51, 68),
    ]
    assert got[2] == [("HEARTBEAT", 2, 1), ("RAW_IMU", 2, 1), ("RADIO_STATUS", 51, 68)]


def test_out_forwards_every_link() -> None:
    """`--out` behind a fleet of two links: a client there (a MAVProxy's view, raw UDP) sees all
    three vehicles in the bytes the links received, and its requests reach the vehicle they
    address on the link it is on (vehicle 3's only on the second link), answered, and counted
    (recorded) by that vehicle's core only."""
    ports = [free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_DGRAM)]
    out_port = free_port(socket.SOCK_DGRAM)
    config = StationConfig(
        connect=f"udpin:127.0.0.1:{ports[0]}", estimate=False, outputs=[f"udpout:127.0.0.1:{out_port}"]
    )
    asks = {sysid: ROLL_RATE_P[sysid].encode() for sysid in (2, 3)}

    def client(sock: socket.socket, stop: threading.Event) -> dict[int, list]:
        """Every packet the output sends, by system; once every vehicle is heard, ask vehicles 2
        and 3 for their roll-rate gain (again every second) until both answer."""
        decoder, encoder = MavlinkDecoder(), Encoder(255, 190)
        seen: dict[int, list] = {}
        sock.settimeout(0.2)
        asked = 0.0
        while not stop.is_set():
            with contextlib.suppress(TimeoutError):
                data, peer = sock.recvfrom(65536)
                for msg in decoder.feed(data, final=True):
                    seen.setdefault(msg.get_srcSystem(), []).append(msg)
                if {1, 2, 3} <= set(seen) and time.monotonic() - asked > 1.0:
                    asked = time.monotonic()
                    for sysid, name in asks.items():
                        ask = mavlink.MAVLink_param_request_read_message(sysid, 1, name, -1)
                        sock.sendto(encoder.encode(ask), peer)
            answered = {m.get_srcSystem() for ms in seen.values() for m in ms if m.get_type() == "PARAM_VALUE"}
            if {2, 3} <= answered:
                break
        return seen

    async def scenario():
        fleet = Fleet(config, [f"udpin:127.0.0.1:{port}" for port in ports])
        received = [link.bus.subscribe("test", maxlen=1_000_000) for link in fleet.links]
        sent: list[list[bytes]] = [[], []]
        for link, packets in zip(fleet.links, sent):
            link.packet_sent.connect(packets.append)
        by_vehicle: dict[int, list[bytes]] = {1: [], 2: [], 3: []}
        fleet.vehicle_added.connect(lambda e: e.station.link.packet_sent.connect(by_vehicle[e.sysid].append))
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", out_port))
        stop = threading.Event()
        await fleet.start()
        try:
            with sim_processes(ports):
                watching = asyncio.create_task(asyncio.to_thread(client, sock, stop))
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(asyncio.shield(watching), 90)
                stop.set()
                seen = await watching
        finally:
            stop.set()
            sock.close()
            await fleet.stop()
        arrived = [{m.raw for m in sub.drain()} for sub in received]
        return seen, arrived, sent, by_vehicle, fleet.outputs[0].snapshot()

    seen, arrived, sent, by_vehicle, output = asyncio.run(scenario())
    assert {1, 2, 3} <= set(seen)
    for sysid, _, link in VEHICLES:  # the vehicles' packets, byte for byte as their link received them
        assert {bytes(m.get_msgbuf()) for m in seen[sysid]} <= arrived[link]
    for sysid, name in asks.items():
        answer = next(m for m in seen[sysid] if m.get_type() == "PARAM_VALUE")
        assert answer.param_id == name.decode()
    # each request went out on the link of the vehicle it addresses, and only there
    names = {name.decode() for name in asks.values()}
    assert [_asked(packets, names) for packets in sent] == [{2}, {3}]
    assert {sysid: _asked(packets, names) for sysid, packets in by_vehicle.items()} == {1: set(), 2: {2}, 3: {3}}
    assert output.packets_in > 0 and output.packets_out > 0


def _asked(packets: list[bytes], names: set[str]) -> set[int]:
    """The systems asked for one of these parameters in these packets."""
    msgs = MavlinkDecoder().feed(b"".join(packets), final=True)
    return {m.target_system for m in msgs if m.get_type() == "PARAM_REQUEST_READ" and m.param_id in names}


def test_commands_address_the_vehicle_sysid_names(tmp_path: Path) -> None:
    """`--sysid` on a link two vehicles share (sysid 1 apm25, sysid 2 pixhawk, each a `gcs sim`
    with a finished flight log): `params get` and `logs download` reach vehicle 2 and only it,
    and a sysid never heard is a one-line error naming the vehicles that were."""
    port = free_port(socket.SOCK_DGRAM)
    connect = ["--connect", f"udpin:127.0.0.1:{port}"]
    log_dirs = {sysid: tmp_path / f"vehicle{sysid}" for sysid in (1, 2)}
    procs = []

    def gcs(*args: str) -> subprocess.CompletedProcess:
        command = [sys.executable, "-m", "gcs", *args, *connect]
        return subprocess.run(command, capture_output=True, text=True, timeout=120, check=False)

    try:
        for sysid, profile in ((1, "apm25"), (2, "pixhawk")):
            command = [sys.executable, "-m", "gcs", "sim", "--profile", profile, "--sysid", str(sysid)]
            command += ["--flight-log", "3", "--log-dir", str(log_dirs[sysid]), "--link", f"udpout:127.0.0.1:{port}"]
            procs.append(subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        got = gcs("params", "get", "ATC_RAT_RLL_P", "SYSID_THISMAV", "--sysid", "2")
        log = gcs("logs", "download", "latest", "--sysid", "2", "--out", str(tmp_path / "out"))
        never = gcs("logs", "list", "--sysid", "7", "--timeout", "4")
    finally:
        for proc in procs:
            stop_process(proc)

    assert got.returncode == 0, got.stderr
    values = {line.split()[0]: float(line.split()[1]) for line in got.stdout.splitlines()}
    truth = truth_params(2, "pixhawk")  # apm25 (vehicle 1) has neither ATC_RAT_RLL_P nor SYSID_THISMAV 2
    assert values == {"ATC_RAT_RLL_P": pytest.approx(truth["ATC_RAT_RLL_P"], rel=1e-6), "SYSID_THISMAV": 2.0}

    assert log.returncode == 0, log.stderr
    (downloaded,) = (tmp_path / "out").glob("log*.bin")
    assert downloaded.read_bytes() == (log_dirs[2] / "00000002.BIN").read_bytes()
    assert all(downloaded.read_bytes() != other.read_bytes() for other in log_dirs[1].glob("*.BIN"))

    assert never.returncode == 1 and never.stdout == ""
    where = f"udpin:127.0.0.1:{port}"
    said = f"gcs logs list: no heartbeat from vehicle sysid 7 on {where} within 4 s (vehicles heard: 1, 2)\n"
    assert never.stderr == said


def test_pose_view_shows_every_vehicle_labelled() -> None:
    """The viser scene with two vehicles on one port (sysid 1 on the bench script, sysid 2 flying
    the quad script): a body for each, labelled with its sysid, each at its own vehicle's
    attitude, and a gain folder per vehicle named the same way."""
    from gcs.core.rotation import euler_to_quat
    from gcs.server.scene import PoseView, display_wxyz, turned

    port = free_port(socket.SOCK_DGRAM)

    def onboard(station):
        point = station.latest_attitudes()[0].get("onboard")
        return None if point is None else (point.roll, point.pitch, point.yaw)

    async def scenario():
        fleet = Fleet(StationConfig(connect=f"udpin:127.0.0.1:{port}"))
        server = DashboardServer(fleet.first, port=0, viser_port=free_port(socket.SOCK_STREAM), fleet=fleet)
        await fleet.start()
        await server.start()
        procs = []
        try:
            for sysid, profile, script in ((1, "apm25", "bench"), (2, "pixhawk", "quad")):
                command = [sys.executable, "-m", "gcs", "sim", "--profile", profile, "--script", script]
                command += ["--sysid", str(sysid), "--link", f"udpout:127.0.0.1:{port}"]
                procs.append(subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))

            def apart() -> bool:  # both vehicles heard, their attitudes more than 3 degrees apart
                attitudes = [onboard(e.station) for e in fleet.vehicles()]
                return (
                    len(attitudes) == 2 and None not in attitudes and max(abs(a - b) for a, b in zip(*attitudes)) > 0.05  # type: ignore[arg-type]
                )

            await wait_for(apart, 90, "two vehicles at different attitudes")
            server.scene.update()
            shown = [
                (
                    view.label.text if view.label else None,
                    view.gains.folder.label,
                    tuple(view.pose.onboard.wxyz),
                    display_wxyz(euler_to_quat(*onboard(view.station))),
                )
                for view in server.scene.views
            ]
            sysids = [next(e.sysid for e in fleet.vehicles() if e.station is v.station) for v in server.scene.views]
        finally:
            for proc in procs:
                stop_process(proc)
            await server.stop()
            await fleet.stop()
        return shown, sysids

    shown, sysids = asyncio.run(scenario())
    assert sorted(sysids) == [1, 2]
    for sysid, (label, folder, drawn, attitude) in zip(sysids, shown):
        assert label == f"sysid {sysid}" and folder == f"Estimator gains, sysid {sysid}"
        assert turned(drawn, attitude) <= PoseView.MIN_TURN + 1e-9  # its own vehicle's attitude (as drawn)
    assert shown[0][2] != pytest.approx(shown[1][2], abs=1e-3)


def test_sysid_not_heard_on_a_silent_link_is_one_line() -> None:
    """`signing setup` and `protocol run` name the sysid they waited for, and that no vehicle
    was heard at all, in one line each (no vehicle on the port; nothing recorded)."""
    where = f"udpin:127.0.0.1:{free_port(socket.SOCK_DGRAM)}"
    runs = {
        "signing setup": ["signing", "setup", "--signing-key", "a passphrase", "--timeout", "2"],
        "protocol": ["protocol", "run", "seed000-bench", "--no-record", "--timeout", "2"],
    }
    for command, args in runs.items():
        done = subprocess.run(
            [sys.executable, "-m", "gcs", *args, "--connect", where, "--sysid", "5"],
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
        )
        said = f"gcs {command}: no heartbeat from vehicle sysid 5 on {where} within 2 s (vehicles heard: none)\n"
        assert done.returncode == 1 and done.stderr == said, (command, done.stderr)


def test_station_heartbeat_reaches_both_mavlink_versions_on_one_link(udp_port: int) -> None:
    """A Pixhawk (MAVLink 2) heard first, then an APM 2.5 (MAVLink 1 only: it drops MAVLink 2
    frames) on the same UDP port: both vehicles hear the station's heartbeat."""
    address = f"udpin:127.0.0.1:{udp_port}"

    async def scenario() -> tuple[int, int]:
        fleet = Fleet(StationConfig(connect=address, estimate=False), [address])
        pixhawk = SimVehicle(profile="pixhawk", sysid=2, script="bench")
        apm25 = SimVehicle(profile="apm25", sysid=1, script="bench")
        await fleet.start()
        tasks = [asyncio.create_task(pixhawk.run(f"udpout:127.0.0.1:{udp_port}"))]
        try:
            await wait_for(lambda: [e.sysid for e in fleet.vehicles()] == [2], 30, "the Pixhawk heard first")
            tasks.append(asyncio.create_task(apm25.run(f"udpout:127.0.0.1:{udp_port}")))
            await wait_for(lambda: len(fleet.vehicles()) == 2, 30, "the APM 2.5 heard too")
            heard = pixhawk.received.get("HEARTBEAT", 0)
            await wait_for(
                lambda: apm25.received.get("HEARTBEAT", 0) >= 3 and pixhawk.received.get("HEARTBEAT", 0) >= heard + 3,
                30,
                "three station heartbeats at each vehicle",
            )
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            await fleet.stop()
        return apm25.received["HEARTBEAT"], pixhawk.received["HEARTBEAT"]

    apm25_heard, pixhawk_heard = asyncio.run(scenario())
    assert apm25_heard >= 3 and pixhawk_heard >= 3


async def _stream(port: int, sysid: int, start: int, count: int, beat_at: int | None = None) -> None:
    """`count` 50 Hz slots of vehicle `sysid` from slot `start` (time since its boot): RAW_IMU and
    ATTITUDE of a vehicle at rest, its HEARTBEAT from slot `beat_at` on, once a second."""
    encoder = Encoder(sysid, 1)
    beat = mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, mavlink.MAV_STATE_ACTIVE, 3
    )
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for k in range(start, start + count):
            msgs = [
                mavlink.MAVLink_raw_imu_message(k * 20_000, 5 * sysid, -8, -1000, 3, -2, 1, 210, -40, 380),
                mavlink.MAVLink_attitude_message(k * 20, 0.01 * sysid, -0.02, 0.5, 0.0, 0.0, 0.0),
            ]
            if beat_at is not None and k >= beat_at and (k - beat_at) % 50 == 0:
                msgs.insert(0, beat)
            sock.sendto(b"".join(encoder.encode(m) for m in msgs), ("127.0.0.1", port))
            await asyncio.sleep(0.02)
    finally:
        sock.close()


def _tlog_imu_systems(folder: Path) -> set[int]:
    """The systems whose RAW_IMU a session's tlog holds."""
    decoder = MavlinkDecoder()
    return {
        sysid
        for _, _, packet in read_tlog_records(folder / layout.TLOG).records()
        for _, kind, sysid, _ in decoder.frames(packet, final=True)
        if kind == "RAW_IMU"
    }


def _sessions_by_vehicle(root: Path) -> dict[int, Path]:
    return {json.loads((f / layout.META).read_text())["vehicle"]["sysid"]: f for f in root.iterdir()}


def _assert_replays_as_live(folder: Path) -> None:
    """The session's replay gives its recorded live dcm estimates, sample for sample."""
    live = gcs.open_session(folder).attitude_df("dcm")[["t", "roll", "pitch", "yaw"]].to_numpy()
    replayed: list = []
    replay = ReplaySession(open_source(folder), 0, ["dcm"])
    replay.points.connect(replayed.extend)
    replay.run_to_end()
    again = np.array([(p.t, p.roll, p.pitch, p.yaw) for p in replayed if p.source == "dcm"])
    assert len(live) > 100 and again.shape == live.shape and (again == live).all(), (folder.name, len(live))


async def _two_vehicles_heard(tmp_path: Path, port: int, feed: Callable[[], Awaitable[None]]) -> list[int | None]:
    """A fleet recording into tmp_path on UDP `port`, fed by `feed` until both vehicles are
    served; the system ids of its vehicles, in the order they were taken."""
    fleet = Fleet(StationConfig(connect=f"udpin:127.0.0.1:{port}", sessions_dir=str(tmp_path), record=True))
    await fleet.start()
    try:
        await wait_for(lambda: fleet.links[0].is_open, 30, "the UDP port open")
        await feed()
        await wait_for(lambda: len(fleet.vehicles()) == 2, 30, "both vehicles")
        return [e.sysid for e in fleet.vehicles()]
    finally:
        await fleet.stop()


def test_a_second_vehicle_estimates_what_came_with_its_first_heartbeat(tmp_path: Path) -> None:
    """Vehicle 2's first heartbeat shares a datagram with its IMU and attitude (a router, a radio,
    a batched read do that). Its new core's recorder kept them; its estimation subscribed only
    when its task first ran and missed them, so the session replayed one sample more than it had
    estimated live (10117 against 10116 with two ArduCopter SITLs). Each session now replays to its
    live estimates exactly."""
    port = free_port(socket.SOCK_DGRAM)

    async def feed() -> None:
        await asyncio.gather(_stream(port, 1, 0, 150, beat_at=0), _stream(port, 2, 0, 150, beat_at=10))

    assert asyncio.run(_two_vehicles_heard(tmp_path, port, feed)) == [1, 2]
    folders = _sessions_by_vehicle(tmp_path)
    assert set(folders) == {1, 2}
    for folder in folders.values():
        _assert_replays_as_live(folder)


def test_a_vehicle_heard_before_the_one_already_streaming_gets_its_own_session(tmp_path: Path) -> None:
    """A station (re)started while vehicles fly: vehicle 1's IMU data arrives before any heartbeat,
    and vehicle 2's heartbeat comes before vehicle 1's. The first core, which took vehicle 1's data,
    was bound to vehicle 2: vehicle 2's session began with vehicle 1's IMU and, its meta naming no
    system, replayed vehicle 1's half second instead of vehicle 2's flight (45 samples of 9021 with
    two ArduCopter SITLs). The first core now serves vehicle 1, whose data it took; each session
    holds its own vehicle's IMU only and replays to its live estimates."""
    port = free_port(socket.SOCK_DGRAM)

    async def feed() -> None:
        await _stream(port, 1, 0, 25)  # vehicle 1 streaming, its heartbeat not yet due
        await asyncio.gather(_stream(port, 2, 0, 150, beat_at=0), _stream(port, 1, 25, 150, beat_at=30))

    served = asyncio.run(_two_vehicles_heard(tmp_path, port, feed))
    folders = _sessions_by_vehicle(tmp_path)
    assert set(folders) == {1, 2}
    for sysid, folder in sorted(folders.items()):
        assert _tlog_imu_systems(folder) == {sysid}, folder.name
        _assert_replays_as_live(folder)
    assert served == [1, 2]  # the first core serves the vehicle whose data it took
