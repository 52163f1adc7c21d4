"""The parameter and tuning REST endpoints, on the real app, against the simulator over UDP:
the token is required for every change when the server is reachable from other machines."""

from __future__ import annotations

import asyncio
import time

import httpx
from conftest import free_port
from live import running_sim, running_station, wait_for
from test_params_protocol import station_and_sim

from gcs.runtime.link import LinkState
from gcs.server.app import create_app
from gcs.server.deps import TOKEN_HEADER

TOKEN = "s3cret-token"


async def _client(station, token, bound_host="0.0.0.0", address="10.0.0.7"):
    app = create_app(station, token=token, bound_host=bound_host)  # default: reachable from other machines
    host = "127.0.0.1" if bound_host == "127.0.0.1" else "gcs"
    return app, httpx.AsyncClient(
        transport=httpx.ASGITransport(app=app, client=(address, 5000)), base_url=f"http://{host}"
    )


def test_tuning_over_rest_needs_the_token():
    async def scenario():
        async with station_and_sim("apm25", estimate=True, param_clamp={"STB_RLL_P": 4.6}) as (station, sim):
            app, client = await _client(station, TOKEN)
            before = sim.params.as_dict()
            async with client:
                # Refused before anything else happens: no session, no download, no write.
                for request in (
                    client.put("/api/tuning/RATE_RLL_P", json={"value": 0.16}),
                    client.put("/api/tuning/RATE_RLL_P", json={"value": 0.16}, headers={TOKEN_HEADER: "wrong"}),
                    client.post("/api/tuning/revert"),
                    client.post("/api/params/download"),
                ):
                    response = await request
                    assert response.status_code == 401, response.text
                    assert "token" in response.json()["detail"]
                assert getattr(app.state, "tuning", None) is None
                read = await client.get("/api/tuning")  # a read never talks to the vehicle
                assert read.status_code == 409 and "/api/params/download" in read.json()["detail"]
                assert "PARAM_SET" not in sim.received and "PARAM_REQUEST_LIST" not in sim.received
                assert sim.params.as_dict() == before

                auth = {TOKEN_HEADER: TOKEN}
                started = await client.post("/api/params/download", headers=auth)
                assert started.status_code == 202 and started.json()["download"] == "started"
                await wait_for(lambda: station.params.complete, 20, "the download")
                table = (await client.get("/api/params")).json()
                assert table["progress"]["state"] == "complete" and len(table["params"]) == len(before)

                # opening the session reads the profile's parameters from the vehicle and fixes the
                # pre-flight values: a read without the token (another site's <img>) does not open it
                reads = sim.received.get("PARAM_REQUEST_READ", 0)
                unopened = await client.get("/api/tuning")
                assert unopened.status_code == 409 and "token" in unopened.json()["detail"], unopened.text
                assert sim.received.get("PARAM_REQUEST_READ", 0) == reads, sim.received
                tuning = (await client.get("/api/tuning", headers=auth)).json()
                assert sim.received["PARAM_REQUEST_READ"] > reads  # what opening it does
                assert (await client.get("/api/tuning")).json() == tuning  # then read without the token
                assert tuning["profile"] == "arducopter-3.2"
                assert tuning["limits"] == {"per_param_interval_s": 0.2, "max_writes_per_s": 5}
                row = next(r for r in tuning["params"] if r["name"] == "RATE_RLL_P")
                assert row["min"] == 0.08 and row["max"] == 0.3 and row["preflight"] == row["current"]

                ok = await client.put("/api/tuning/RATE_RLL_P", json={"value": 0.16}, headers=auth)
                assert ok.status_code == 200, ok.text
                assert ok.json()["verified"] is True and abs(ok.json()["new"] - 0.16) < 1e-6
                assert abs(sim.params["RATE_RLL_P"] - 0.16) < 1e-6
                too_soon = await client.put("/api/tuning/RATE_RLL_P", json={"value": 0.17}, headers=auth)
                assert too_soon.status_code == 429 and "wait" in too_soon.json()["detail"]
                refused = await client.put("/api/tuning/RATE_RLL_P", json={"value": 0.5}, headers=auth)
                assert refused.status_code == 422
                assert "outside the allowed range [0.08, 0.3]" in refused.json()["detail"]
                other = await client.put("/api/tuning/FRAME", json={"value": 0}, headers=auth)
                assert other.status_code == 422 and "not in the tuning profile" in other.json()["detail"]
                bad = await client.put("/api/tuning/RATE_PIT_P", json={"value": "fast"}, headers=auth)
                assert bad.status_code == 422
                clamped = await client.put("/api/tuning/STB_RLL_P", json={"value": 5.0}, headers=auth)
                assert clamped.status_code == 409
                assert clamped.json()["detail"] == "STB_RLL_P: vehicle stored 4.6, asked 5"

                reverted = await client.post("/api/tuning/revert", headers=auth)
                assert reverted.status_code == 200, reverted.text
                assert {p["name"] for p in reverted.json()["restored"]} == {"RATE_RLL_P", "STB_RLL_P"}
                assert sim.params.as_dict() == before

            writes = [e.data | {"client": e.client} for e in station.events.recent if e.kind == "param"]
            assert [(w["name"], w["verified"], w["client"]) for w in writes] == [
                ("RATE_RLL_P", True, "api:10.0.0.7"),
                ("STB_RLL_P", False, "api:10.0.0.7"),
                ("RATE_RLL_P", True, "api:10.0.0.7"),
                ("STB_RLL_P", True, "api:10.0.0.7"),
            ]

    asyncio.run(asyncio.wait_for(scenario(), 90))


def test_a_loopback_server_needs_the_token_too():
    """Any page the engineer has open can send requests to 127.0.0.1: loopback is no credential."""

    async def scenario():
        async with station_and_sim("px4", estimate=True) as (station, sim):
            _, client = await _client(station, TOKEN, bound_host="127.0.0.1", address="127.0.0.1")
            before = sim.params["MC_ROLL_P"]
            async with client:
                refused = await client.put("/api/tuning/MC_ROLL_P", json={"value": 6.0})
                assert refused.status_code == 401, refused.text
                assert sim.params["MC_ROLL_P"] == before and "PARAM_SET" not in sim.received
                ok = await client.put("/api/tuning/MC_ROLL_P", json={"value": 6.0}, headers={TOKEN_HEADER: TOKEN})
                assert ok.status_code == 200, ok.text
            assert sim.params["MC_ROLL_P"] == 6.0

    asyncio.run(asyncio.wait_for(scenario(), 60))


def test_a_revert_the_vehicle_never_answers_is_a_timeout_not_a_refusal():
    """A vehicle that takes no write (every PARAM_VALUE lost) after a tuning write: POST
    /api/tuning/revert answered 422, the code of a value the vehicle or the profile refused, and
    the page said "refused" for writes that got no answer at all. Now 504, "no answer from the
    vehicle". With the link lost, though, nothing is sent: the revert is refused at once (422,
    saying so); it waited 10 s per changed parameter for a heartbeat, then answered 504."""

    async def scenario():
        port = free_port()
        async with running_station(f"udpin:127.0.0.1:{port}", heartbeat_timeout=1.0) as station:
            app, client = await _client(station, TOKEN)
            auth = {TOKEN_HEADER: TOKEN}
            async with client:
                async with running_sim(f"udpout:127.0.0.1:{port}", profile="apm25") as sim:
                    assert await station.link.wait_connected(10)
                    await client.post("/api/params/download", headers=auth)
                    await wait_for(lambda: station.params.complete, 20, "the download")
                    wrote = await client.put("/api/tuning/RATE_RLL_P", json={"value": 0.16}, headers=auth)
                    assert wrote.status_code == 200, wrote.text
                    sim.param_drop = 1.0
                    unanswered = await client.post("/api/tuning/revert", headers=auth)
                await wait_for(lambda: station.link.state == LinkState.LOST, 10, "the vehicle lost")
                asked = time.monotonic()
                lost = await client.post("/api/tuning/revert", headers=auth)
                return unanswered, lost, time.monotonic() - asked

    unanswered, lost, took = asyncio.run(asyncio.wait_for(scenario(), 90))
    assert unanswered.status_code == 504, unanswered.text
    detail = unanswered.json()["detail"]
    assert detail.startswith("revert incomplete (0 restored): RATE_RLL_P: no echo after 3 writes"), detail
    assert lost.status_code == 422, lost.text
    assert lost.json()["detail"] == (
        "not reverted, nothing written: the link to the vehicle is lost; try again when it is back"
    )
    assert took < 2.0, took
