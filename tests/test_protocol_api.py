"""The dashboard's protocol panel API (/api/protocol) on a real Station fed by the simulator's
bench script over UDP: start a protocol from a user file, watch it complete a step by itself,
skip the next one; the run's events in the station's event log."""

from __future__ import annotations

import asyncio

import httpx
from live import running_sim, running_station, wait_for

from gcs.server.dashboard import DashboardServer

#: The bench script turns to roll -30° at t = 2-5 s and holds it until t = 10 s.
PROTOCOL = """
name = "two-steps"
detect_source = "truth"
[defaults]
hold_s = 1.0
tolerance_deg = 2.0
[[steps]]
axis = "roll"
target_deg = -30.0
[[steps]]
axis = "pitch"
target_deg = 30.0
"""


def test_protocol_panel_api_runs_a_step_and_skips_one(udp_port, tmp_path):
    path = tmp_path / "two.toml"
    path.write_text(PROTOCOL)
    asyncio.run(_scenario(udp_port, str(path)))


async def _scenario(udp_port: int, path: str) -> None:
    async with running_station(f"udpin:127.0.0.1:{udp_port}") as station:
        server = DashboardServer(station, port=0, viser=False)
        await server.start()
        try:
            async with httpx.AsyncClient(
                base_url=f"http://127.0.0.1:{server.port}", headers=server.auth_headers
            ) as api:
                listed = (await api.get("/api/protocol")).json()
                assert "seed000-bench" in listed["available"] and listed["run"] is None
                bad = await api.post("/api/protocol/start", json={"name": "no-such-protocol"})
                assert bad.status_code == 422 and "seed000-bench" in bad.json()["detail"]
                started = (await api.post("/api/protocol/start", json={"name": path})).json()["run"]
                assert started["state"]["prompt"].startswith("rotate to roll -30") and started["running"]
                # the vehicle starts now, so its script begins with the first step's angle
                async with running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="bench"):
                    await wait_for(lambda: station.protocol.index == 1, 90, "step 1 held")
                run = (await api.get("/api/protocol")).json()["run"]
                assert run["state"]["completed"] == 1 and run["state"]["step"] == 1
                truth = next(m for m in run["results"] if m["source"] == "truth")
                assert truth["label"] == "roll -30" and truth["mre_last_pct"] < 0.5
                assert {m["source"] for m in run["results"]} >= {"truth", "onboard", "dcm", "kf", "ekf"}
                run = (await api.post("/api/protocol/skip")).json()["run"]
                assert run["state"]["finished"] and not run["running"] and run["state"]["skipped"] == 1
                assert (await api.post("/api/protocol/skip")).status_code == 404  # nothing left to skip
        finally:
            await server.stop()
        actions = [e.data["action"] for e in station.events.recent if e.kind == "protocol"]
        assert actions == ["start", "prompt", "hold", "prompt", "skip", "end"]
