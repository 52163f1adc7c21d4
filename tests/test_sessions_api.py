"""The sessions REST router against a real uvicorn, a recording station and the simulator:
recording control and notes, listing, export download, replay control and what-if."""

from __future__ import annotations

import asyncio
import io
import json

import httpx
import pyarrow.parquet as pq
from live import running_station, served_api, sim_process, wait_for

from gcs.commands.cli import build_parser
from gcs.commands.options import station_config
from gcs.mavlink.sampling import UNREADY
from gcs.mavlink.tlog import read_tlog_records
from gcs.runtime.station import Station, StationConfig
from gcs.server.dashboard import DashboardServer
from gcs.sessions import layout
from gcs.transport.address import free_port

ATTITUDE = 30


def msg_id(raw: bytes) -> int:
    """The message id of one MAVLink 1 or 2 packet."""
    return raw[5] if raw[0] == 0xFE else int.from_bytes(raw[7:10], "little")


def test_sessions_api(udp_port, tmp_path):
    asyncio.run(scenario(udp_port, tmp_path))


async def scenario(udp_port: int, root) -> None:
    async with (
        running_station(f"udpin:127.0.0.1:{udp_port}", sessions_dir=str(root), record=True) as station,
        sim_process(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad", speed=4.0),
    ):
        server = DashboardServer(station, port=0, viser=False)
        await server.start()
        try:
            async with httpx.AsyncClient(
                base_url=f"http://127.0.0.1:{server.port}", timeout=30, headers=server.auth_headers
            ) as api:
                await wait_for(lambda: station.estimation.pipeline.imu_samples > 300, 60, "IMU samples")
                assert (await api.get("/api/recording")).json()["state"] == "recording"
                assert (await api.post("/api/recording/note", json={"text": "gusty"})).status_code == 200
                stopped = (await api.post("/api/recording/stop")).json()
                assert stopped["state"] == "stopped"
                # no session to keep it: refused, where it was answered ok and kept nowhere
                lost = await api.post("/api/recording/note", json={"text": "after landing"})
                assert lost.status_code == 409 and "not recording" in lost.json()["detail"], lost.text
                sessions = (await api.get("/api/sessions")).json()
                assert len(sessions) == 1 and not sessions[0]["open"] and sessions[0]["duration_s"] > 0
                name = sessions[0]["name"]
                events = (root / name / layout.EVENTS).read_text().splitlines()
                assert any(json.loads(e).get("text") == "gusty" for e in events)

                csv = await api.get(f"/api/sessions/{name}/export", params={"format": "csv"})
                assert csv.status_code == 200
                assert csv.text.splitlines()[0] == '"wall_time","t","source","roll_deg","pitch_deg","yaw_deg"'
                parquet = await api.get(f"/api/sessions/{name}/export", params={"format": "parquet"})
                assert pq.read_table(io.BytesIO(parquet.content)).num_rows == len(csv.text.splitlines()) - 1
                assert (await api.get("/api/sessions/../etc/export")).status_code == 404
                assert (await api.get("/api/sessions/..%2Fetc/export")).status_code == 404

                assert (await api.post("/api/recording/start")).json()["state"] == "recording"
                assert len((await api.get("/api/sessions")).json()) == 2

                # A replay is one read-only request, computed in the worker: every source's series.
                replay = await api.get("/api/replay", params={"source": name})
                assert replay.status_code == 200, replay.text
                body = replay.json()
                assert body["kind"] == "session" and body["frames"] > 0
                # the onboard series, with the boot's onboard-unready one (ATTITUDE before the first
                # EKF_STATUS_REPORT), is every ATTITUDE of the session's tlog (read independently)
                records = [raw for _, raw in read_tlog_records(root / name / layout.TLOG)]
                attitudes = sum(msg_id(raw) == ATTITUDE for raw in records)
                t, roll = body["points"]["onboard"][0], body["points"]["onboard"][1]
                unready = body["points"].get(UNREADY, [[]])[0]
                assert len(t) == len(roll) and len(t) + len(unready) == attitudes > 100
                assert all(b > a for a, b in zip(t, t[1:]))
                assert not unready or max(unready) < min(t)  # the boot's first ATTITUDE only
                assert len(body["points"]["dcm"][0]) == body["imu_samples"] > 100
                assert {(r["estimator"], r["reference"]) for r in body["table"]} >= {
                    ("dcm", "onboard"),
                    ("ekf", "onboard"),
                }
                # one estimator, another gain: only it runs, and its figures change
                other = (
                    await api.get("/api/replay", params={"source": name, "estimator": "dcm", "gain": "kp_rp=0.9"})
                ).json()
                assert set(other["estimators"]) == {"dcm"} and "kf" not in other["points"]
                rms = {(r["estimator"], r["reference"]): r["rms_deg"] for r in body["table"]}
                assert other["table"][0]["rms_deg"] != rms[("dcm", other["table"][0]["reference"])]
                assert (await api.get("/api/replay", params={"source": name, "estimator": "nope"})).status_code == 422

                result = (
                    await api.post("/api/whatif", json={"source": name, "estimator": "dcm", "gains": {"kp_rp": 0.9}})
                ).json()
                assert len(result["t"]) == len(result["old"]["roll"]) == len(result["new"]["roll"]) > 100
                assert {row["reference"] for row in result["table"]} >= {"onboard", "truth"}
                assert result["table"][0]["old_rms"] != result["table"][0]["new_rms"]
                bad = await api.post("/api/whatif", json={"source": name, "estimator": "dcm", "gains": {"kp_rp": -5}})
                assert bad.status_code == 422 and "kp_rp" in bad.text

            async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{server.port}") as api:  # no token
                assert (await api.post("/api/recording/stop")).status_code == 401
                assert (await api.post("/api/recording/start")).status_code == 401
                assert (await api.get("/api/replay", params={"source": name})).status_code == 200  # read-only
                assert (await api.get("/api/sessions")).status_code == 200
        finally:
            await server.stop()


def test_a_station_that_does_not_record_lists_the_sessions_of_its_record_dir(tmp_path):
    """`gcs serve --no-record --record-dir DIR`: the sessions (and so the replay and what-if)
    lists read DIR, where they read ./sessions whatever DIR was."""
    (tmp_path / "2026-12-01_10-00-00_quad").mkdir()
    (tmp_path / "2026-12-01_10-00-00_quad" / layout.META).write_text("{}")
    argv = ["serve", "--connect", f"udpin:127.0.0.1:{free_port()}", "--no-record", "--record-dir", str(tmp_path)]
    assert asyncio.run(listed(station_config(build_parser(["serve"]).parse_args(argv)))) == ["2026-12-01_10-00-00_quad"]


def test_the_record_flags_give_the_one_sessions_folder_and_whether_to_record(tmp_path):
    """StationConfig kept the folder twice: record_dir (None when not recording) and sessions_dir
    (the lists' folder when not recording), equal whenever both were set, the second unread then.
    The flags now set the one folder and whether to record into it, as they did."""
    link = ["--connect", f"udpin:127.0.0.1:{free_port()}"]
    folder = ["--record-dir", str(tmp_path)]
    for command, flags, record in (
        (["serve"], folder, True),
        (["serve"], [*folder, "--no-record"], False),
        (["status"], folder, False),  # a quick look records only when asked
        (["status"], [*folder, "--record"], True),
        (["params", "get"], [*folder, "--record"], True),
    ):
        config = station_config(build_parser(command).parse_args([*command, *link, *flags]))
        assert (config.sessions_dir, config.record) == (str(tmp_path), record), (command, flags)
    config = station_config(build_parser(["serve"]).parse_args(["serve", *link]))
    assert (config.sessions_dir, config.record) == ("sessions", True)


async def listed(config: StationConfig) -> list[str]:
    """The names GET /api/sessions lists from a station of `config` that records nothing."""
    station = Station(config)
    await station.start()
    try:
        assert station.recorder is None
        async with served_api(station) as api:
            return [s["name"] for s in (await api.get("/api/sessions")).json()]
    finally:
        await station.stop()


def test_a_link_in_the_record_dir_to_elsewhere_is_not_listed(tmp_path):
    """A log or session folder in the recording folder that links elsewhere (a folder copied from
    a stick): replay and export refuse it (404), so the lists do not offer it, nor tell the size
    of the file it points to."""
    root, elsewhere = tmp_path / "sessions", tmp_path / "elsewhere"
    root.mkdir()
    (elsewhere / "2026-12-01_10-00-00_quad").mkdir(parents=True)
    (elsewhere / "2026-12-01_10-00-00_quad" / layout.META).write_text("{}")
    (elsewhere / "secret.tlog").write_bytes(b"x" * 1234)
    (root / "2026-12-02_10-00-00_quad").symlink_to(elsewhere / "2026-12-01_10-00-00_quad")
    (root / "flight.tlog").symlink_to(elsewhere / "secret.tlog")
    (root / "2026-12-03_10-00-00_quad").mkdir()
    (root / "2026-12-03_10-00-00_quad" / layout.META).write_text("{}")
    (root / "own.tlog").write_bytes(b"")

    async def scenario() -> tuple[list[str], list[str], list[int]]:
        config = StationConfig(connect=f"udpin:127.0.0.1:{free_port()}", sessions_dir=str(root))
        station = Station(config)
        await station.start()
        try:
            async with served_api(station) as api:
                sessions = [s["name"] for s in (await api.get("/api/sessions")).json()]
                logs = [log["name"] for log in (await api.get("/api/logs")).json()]
                refused = [(await api.get("/api/replay", params={"source": n})).status_code for n in ("flight.tlog",)]
                return sessions, logs, refused
        finally:
            await station.stop()

    sessions, logs, refused = asyncio.run(scenario())
    assert refused == [404]
    assert sessions == ["2026-12-03_10-00-00_quad"]
    assert logs == ["own.tlog"]
