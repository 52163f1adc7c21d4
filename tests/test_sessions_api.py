"""The sessions REST router against a real uvicorn, a recording station and the simulator:
recording control and notes, listing, export download, replay control and what-if."""

from __future__ import annotations

import asyncio
import io
import json
import time

import httpx
import pyarrow.parquet as pq
from live import running_sim, running_station, wait_for

from gcs.mavlink.tlog import read_tlog_records
from gcs.server.dashboard import DashboardServer
from gcs.sessions import layout


def test_sessions_api(udp_port, tmp_path):
    asyncio.run(scenario(udp_port, tmp_path))


async def scenario(udp_port: int, root) -> None:
    async with (
        running_station(f"udpin:127.0.0.1:{udp_port}", record_dir=str(root)) as station,
        running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad", speed=4.0),
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

                loaded = (await api.post("/api/replay", json={"source": name, "speed": 0})).json()
                assert loaded["kind"] == "session" and loaded["frames"] > 0
                # speed 0: as fast as it goes, which on a loaded machine is still seconds
                deadline = time.monotonic() + 60
                while not (await api.get("/api/replay")).json()["finished"]:
                    assert time.monotonic() < deadline, "the replay at speed 0 did not finish within 60 s"
                    await asyncio.sleep(0.05)
                seeked = (await api.post("/api/replay/seek", json={"offset_s": 1.0})).json()
                # the first record at least 1 s after the first (the tlog read independently of the replay)
                times = [(usec & ~3) / 1e6 for usec, _ in read_tlog_records(root / name / layout.TLOG)]
                first = next(k for k, t in enumerate(times) if t >= times[0] + 1.0)
                assert (seeked["frame"], seeked["position_s"]) == (first, round(times[first] - times[0], 3))
                assert not seeked["seeking"]
                assert (await api.post("/api/replay/speed", json={"speed": 2})).json()["speed"] == 2
                assert (await api.post("/api/replay/pause")).json()["playing"] is False

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
                assert (await api.post("/api/replay/play")).status_code == 401
                assert (await api.get("/api/sessions")).status_code == 200
        finally:
            await server.stop()
