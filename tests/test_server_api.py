"""The REST API against a real uvicorn on a free port, fed by the simulator over UDP."""

from __future__ import annotations

import asyncio

import httpx
from live import running_sim, running_station, wait_for

from gcs.runtime.snapshots import StreamRate
from gcs.server.dashboard import DashboardServer
from gcs.server.deps import TOKEN_HEADER, token_id

NO_RATE = StreamRate(0.0, 0.0, None, None)


def test_rest_api_status_estimates_gains_token(udp_port):
    asyncio.run(api_scenario(udp_port))


async def api_scenario(udp_port: int) -> None:
    async with (
        running_station(f"udpin:127.0.0.1:{udp_port}") as station,
        running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad"),
    ):
        server = DashboardServer(station, port=0, viser=False)
        await server.start()
        try:
            async with httpx.AsyncClient(
                base_url=f"http://127.0.0.1:{server.port}", headers=server.auth_headers
            ) as api:
                await wait_for(
                    lambda: {"onboard", "truth", "dcm", "kf", "ekf"} <= set(station.estimation.pipeline.latest),
                    15,
                    "every source",
                )
                await wait_for(  # the status is the station's snapshot, published once a second
                    lambda: (
                        station.snapshot.streams.messages.get("ATTITUDE", NO_RATE).achieved_hz > 30
                        and all(e.errors for e in station.snapshot.estimation.estimators.values())
                    ),
                    15,
                    "a snapshot with rates and errors",
                )
                await check_status_and_estimates(api)
                await check_gains(api, station)
                assert (await api.get("/openapi.json")).json()["paths"]["/api/estimators/{name}/gains/{gain}"]["put"]
                page = await api.get("/")
                assert page.status_code == 200 and "uPlot.iife.min.js" in page.text
                assert (await api.get("/vendor/uplot/uPlot.iife.min.js")).status_code == 200
        finally:
            await server.stop()
        # Bound to every interface (reachable from other machines): changes need the token.
        exposed = DashboardServer(station, host="0.0.0.0", port=0, viser=False)
        await exposed.start()
        try:
            assert exposed.token and exposed.url.endswith(f"/?token={exposed.token}")
            async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{exposed.port}") as api:
                url = "/api/estimators/ekf/gains/gyro_noise"
                assert (await api.put(url, json={"value": 0.02})).status_code == 401
                assert (await api.put(url, json={"value": 0.02}, headers={"X-GCS-Token": "wrong"})).status_code == 401
                ok = await api.put(url, json={"value": 0.02}, headers={"X-GCS-Token": exposed.token})
                assert ok.status_code == 200
                assert (await api.get("/api/status")).json()["authorised"] is False
                assert (await api.get("/api/estimates")).status_code == 200  # reading needs no token
        finally:
            await exposed.stop()


async def check_status_and_estimates(api: httpx.AsyncClient) -> None:
    status = (await api.get("/api/status")).json()
    assert status["link"]["state"] == "connected"
    assert status["link"]["streams"]["ATTITUDE"]["requested_hz"] == 50
    assert status["link"]["streams"]["ATTITUDE"]["achieved_hz"] > 30
    assert 0 <= status["data_age_ms"] < 1000
    assert set(status["estimators"]) == {"dcm", "kf", "ekf"}
    assert all(isinstance(e["reliable"], bool) for e in status["estimators"].values())
    assert status["authorised"] is True
    sources = (await api.get("/api/estimates")).json()["sources"]
    assert {"onboard", "ahrs2", "truth", "dcm", "kf", "ekf"} <= set(sources)
    assert sources["onboard"]["kind"] == "reference" and sources["onboard"]["errors"] == {}
    for name in ("dcm", "kf", "ekf"):
        errors = sources[name]["errors"]
        assert set(errors) == {"onboard", "truth"}, errors
        assert errors["onboard"]["n"] > 0 and all(0 <= v < 30 for v in errors["truth"]["session_rms_deg"])
    assert -180 <= sources["dcm"]["yaw_deg"] <= 180


async def check_gains(api: httpx.AsyncClient, station) -> None:
    """A change over REST reaches the running estimator and the event log (refusals, listing and
    presets are covered against a fake station in test_server_routes.py)."""
    r = await api.put("/api/estimators/dcm/gains/kp_rp", json={"value": 0.5})
    assert r.status_code == 200 and r.json() == {"estimator": "dcm", "gain": "kp_rp", "old": 0.2, "new": 0.5}
    assert station.estimation.pipeline.estimators["dcm"].gains["kp_rp"] == 0.5
    event = station.events.recent[-1]
    assert (event.kind, event.client) == ("gain", "api:127.0.0.1")
    assert event.data == {
        "estimator": "dcm",
        "gain": "kp_rp",
        "old": 0.2,
        "new": 0.5,
        "user_agent": api.headers["user-agent"],
        "token_id": token_id(api.headers[TOKEN_HEADER]),
    }
