"""The REST routers against a fake station that implements the facade's protocol (real
estimators and gain declarations, canned snapshots): fast, no sockets to a vehicle. The live
end-to-end scenarios are in test_server_api.py and test_sessions_api.py."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from fastapi import HTTPException
from fastapi.testclient import TestClient
from starlette.responses import PlainTextResponse
from starlette.routing import Route

from gcs.core.estimation import AttitudePoint
from gcs.core.estimators import registry
from gcs.core.estimators.base import AttitudeEstimator
from gcs.runtime.events import EventLog
from gcs.runtime.signal import Signal
from gcs.runtime.snapshots import (
    ErrorStats,
    EstimationSnapshot,
    EstimatorSnapshot,
    LinkCounters,
    LinkSnapshot,
    RecordingSnapshot,
    SourceAttitude,
    StationSnapshot,
    StreamRate,
    StreamsSnapshot,
    VehicleSnapshot,
)
from gcs.runtime.supervisor import PartStatus
from gcs.server.app import create_app
from gcs.server.deps import TOKEN_HEADER, get_station, token_id
from gcs.server.guard import MAX_BODY
from gcs.server.models import VehicleSummary
from gcs.server.polled_answers import PolledAnswers
from gcs.server.ratelimit import MAX_CLIENTS, RateLimit

RECORDING_OFF = RecordingSnapshot("off", None, None, 0, None, 0, 0, 0, None)


def error_stats(n: int, rms: float) -> ErrorStats:
    return ErrorStats(n, [rms] * 3, [2 * rms] * 3, [rms] * 3, [2 * rms] * 3)


def canned_snapshot() -> StationSnapshot:
    counters = LinkCounters(
        1000,
        50_000,
        800,
        20,
        12_345.6,
        {"ATTITUDE": 49.8},
        {"ATTITUDE": 500},
        2,
        1,
        7,
        0,
        3,
        0.003,
        {"1/1": 3},
        0,
        1000,
    )
    link = LinkSnapshot("vehicle", "udpin:0.0.0.0:14550", "connected", True, None, 1, 1, 2, 0.4, counters, [])
    estimators = {
        "dcm": EstimatorSnapshot(
            "ardupilot",
            {"kp_rp": 0.2},
            {"accel_norm": 9.8},
            True,
            "",
            50.1,
            0.02,
            0,
            {"onboard": error_stats(400, 0.5), "ahrs2": error_stats(400, 0.7), "truth": error_stats(400, 0.3)},
        ),
        "kf": EstimatorSnapshot(
            "telemetry", {}, {}, False, "raw IMU at 20.0 Hz, below the 50 Hz needed", 20.0, None, 0, {}
        ),
    }
    latest = {
        "onboard": SourceAttitude("onboard", "reference", 12.5, 1.0, -2.0, 90.0),
        "dcm": SourceAttitude("dcm", "estimator", 12.5, 1.1, -2.1, 90.5),
    }
    return StationSnapshot(
        published=time.time(),
        link=link,
        vehicle=VehicleSnapshot(1, 1, "ArduPilot", "QUADROTOR", 2, True, 0, "ACTIVE", "4.5.7", 0, 30),
        streams=StreamsSnapshot(
            "SET_MESSAGE_INTERVAL",
            3,
            {"ATTITUDE": StreamRate(50.0, 49.8, 0.996, "ACCEPTED", 50.0, "SET_MESSAGE_INTERVAL")},
        ),
        outputs=[],
        estimation=EstimationSnapshot("RAW_IMU", 600, None, estimators, latest),
        recording=RECORDING_OFF,
        parts=[PartStatus("link", "running"), PartStatus("estimation", "failed", "RuntimeError: boom", 1.0)],
    )


class FakeStation:
    """The facade with real estimators and a canned snapshot."""

    def __init__(self) -> None:
        self.events = EventLog()
        self.params = None
        self.points: Signal[[list[AttitudePoint]]] = Signal()
        self.published: Signal[[StationSnapshot]] = Signal()
        self.estimators = {name: registry.create(name) for name in ("dcm", "kf")}
        self.snapshot_reads = 0
        self._snapshot = canned_snapshot()

    @property
    def snapshot(self) -> StationSnapshot:
        self.snapshot_reads += 1
        return self._snapshot

    @property
    def recording_root(self) -> Path:
        return Path("sessions")

    def recording_snapshot(self) -> RecordingSnapshot:
        return RECORDING_OFF

    def latest_attitudes(self):
        return {}, {}

    def estimator_names(self) -> list[str]:
        return list(self.estimators)

    def pace_points(self, interval) -> None:
        self.pace = interval

    def estimator(self, name: str) -> AttitudeEstimator:
        if name not in self.estimators:
            raise KeyError(f"unknown estimator {name!r}")
        return self.estimators[name]

    def set_gain(self, estimator: str, gain: str, value: float, client: str) -> tuple[float, float]:
        old, new = self.estimator(estimator).set_gain(gain, value)
        self.events.record("gain", client, estimator=estimator, gain=gain, old=old, new=new)
        return old, new

    def reset_gains(self, estimator: str, preset: str | None, client: str) -> dict[str, tuple[float, float]]:
        est = self.estimator(estimator)
        before = dict(est.gains.values)
        est.gains.apply_preset(preset or est.DEFAULT_PRESET)
        return {k: (before[k], v) for k, v in est.gains.values.items() if v != before[k]}


@pytest.fixture
def station() -> FakeStation:
    return FakeStation()


TOKEN = "s3cret"


def client_of(station: FakeStation, **options) -> TestClient:
    """A client of the app that carries the token, as a script given it does."""
    app = create_app(station, token=TOKEN, **options)  # type: ignore[arg-type]
    return TestClient(app, base_url="http://127.0.0.1", headers={TOKEN_HEADER: TOKEN})


@pytest.fixture
def api(station: FakeStation) -> TestClient:
    return client_of(station)


def test_status_is_the_published_snapshot(api: TestClient, station: FakeStation):
    status = api.get("/api/status").json()
    assert station.snapshot_reads == 1  # read once, nothing recomputed
    assert status["link"]["state"] == "connected" and status["link"]["crc_errors"] == 2
    assert status["link"]["streams"]["ATTITUDE"] == {
        "requested_hz": 50.0,
        "achieved_hz": 49.8,
        "ratio": 0.996,
        "ack": "ACCEPTED",
        "accepted_hz": 50.0,
        "method": "SET_MESSAGE_INTERVAL",
        "reason": None,
    }
    assert status["vehicle"]["firmware"] == "4.5.7" and status["imu_type"] == "RAW_IMU"
    assert status["estimators"]["kf"]["reliable"] is False and "20.0 Hz" in status["estimators"]["kf"]["reason"]
    failed = [p for p in status["parts"] if p["state"] == "failed"]
    assert failed == [{"name": "estimation", "state": "failed", "error": "RuntimeError: boom", "since": 1.0}]
    assert status["authorised"] is True and status["clients"] == []


@pytest.mark.parametrize("path", ["/status", "/estimates"])
@pytest.mark.parametrize("vehicle", [False, True])
def test_polls_answered_before_routing_as_the_route_answers(
    api: TestClient, station: FakeStation, path: str, vehicle: bool
):
    """GET /api/status and /api/estimates, and the same under /api/vehicles/{sysid}/ (a page
    opened for one vehicle), skip FastAPI's router and dependencies (gcs.server.polled_answers)
    and give what the route gives: the same bytes and headers as the app without the middleware."""
    url = f"/api/vehicles/{station.snapshot.vehicle.sysid}{path}" if vehicle else f"/api{path}"
    routed_api = client_of(station)
    routed_api.app.user_middleware = [  # type: ignore[attr-defined]
        m
        for m in routed_api.app.user_middleware  # type: ignore[attr-defined]
        if m.cls is not PolledAnswers
    ]
    routed = routed_api.get(url)
    assert routed.status_code == 200
    api.app.dependency_overrides[get_station] = refuse  # type: ignore[attr-defined]
    answered = api.get(url)  # the override is never reached: no dependency is solved
    assert answered.status_code == 200
    assert answered.content == routed.content
    assert answered.headers == routed.headers  # content type and length, the guard's security headers
    assert api.get(url, headers={"host": "evil.example"}).status_code == 403  # the guard first


def test_a_vehicle_not_heard_is_left_to_the_router(api: TestClient):
    """Its 404 names the vehicle list, as every route under /api/vehicles/{sysid}/ does."""
    missing = api.get("/api/vehicles/99/status")
    assert missing.status_code == 404 and "no vehicle with sysid 99" in missing.json()["detail"]


def test_vehicle_list_answered_before_routing(api: TestClient, station: FakeStation):
    """GET /api/vehicles (vehicles.js polls it every 2 s) skips the router too, with the route's
    fields, and the guard still applies."""
    # a route ahead of every other: whatever the router gives /api/vehicles now refuses
    api.app.router.routes.insert(0, Route("/api/vehicles", PlainTextResponse("the router ran", 503)))  # type: ignore[attr-defined]
    answered = api.get("/api/vehicles")
    assert answered.status_code == 200 and answered.headers["content-type"] == "application/json"
    (vehicle,) = answered.json()
    assert vehicle["sysid"] == station.snapshot.vehicle.sysid and vehicle["first"] is True
    assert vehicle["prefix"] == f"/api/vehicles/{station.snapshot.vehicle.sysid}"
    assert set(vehicle) == set(VehicleSummary.model_fields)
    assert "x-content-type-options" in answered.headers  # the guard's security headers
    assert api.get("/api/vehicles", headers={"host": "evil.example"}).status_code == 403


async def refuse() -> None:
    raise HTTPException(503, "the router ran")


def test_estimates_report_errors_against_onboard_and_truth_only(api: TestClient):
    sources = api.get("/api/estimates").json()["sources"]
    assert sources["onboard"]["kind"] == "reference" and sources["onboard"]["errors"] == {}
    assert set(sources["dcm"]["errors"]) == {"onboard", "truth"}
    assert sources["dcm"]["errors"]["truth"]["session_rms_deg"] == [0.3, 0.3, 0.3]
    assert sources["dcm"]["yaw_deg"] == 90.5


def test_gain_listing_change_and_refusals(api: TestClient, station: FakeStation):
    listing = {e["name"]: e for e in api.get("/api/estimators").json()}
    kp = next(g for g in listing["dcm"]["gains"] if g["name"] == "kp_rp")
    assert (kp["min"], kp["max"], kp["scale"]) == (0.0, 50.0, "log")

    ok = api.put("/api/estimators/dcm/gains/kp_rp", json={"value": 0.5})
    assert ok.status_code == 200 and ok.json() == {"estimator": "dcm", "gain": "kp_rp", "old": 0.2, "new": 0.5}
    assert station.estimators["dcm"].gains["kp_rp"] == 0.5
    event = station.events.recent[-1]
    assert (event.kind, event.client, event.data["new"]) == ("gain", "api:testclient", 0.5)
    # the audit names the client: its user agent and which token it carried (an id, never the token)
    assert event.data["user_agent"] == "testclient" and event.data["token_id"] == token_id(TOKEN) != TOKEN

    assert api.put("/api/estimators/dcm/gains/kp_rp", json={"value": 99}).status_code == 422
    assert station.estimators["dcm"].gains["kp_rp"] == 0.5  # a refused value changes nothing
    assert api.put("/api/estimators/dcm/gains/bogus", json={"value": 1}).status_code == 404
    assert api.put("/api/estimators/nope/gains/kp_rp", json={"value": 1}).status_code == 404
    assert api.put("/api/estimators/dcm/gains/kp_rp", json={"value": "abc"}).status_code == 422

    reset = api.post("/api/estimators/dcm/preset", json={}).json()
    assert {"gain": "kp_rp", "old": 0.5, "new": 0.2, "estimator": "dcm"} in reset["changes"]


def test_changes_need_the_token_even_on_loopback(station: FakeStation):
    api = TestClient(create_app(station, token=TOKEN), base_url="http://127.0.0.1")  # type: ignore[arg-type]
    url = "/api/estimators/dcm/gains/kp_rp"
    assert api.put(url, json={"value": 0.3}).status_code == 401
    assert api.put(url, json={"value": 0.3}, headers={TOKEN_HEADER: "wrong"}).status_code == 401
    assert api.put(url, json={"value": 0.3}, headers={"Authorization": "Bearer s3cret"}).status_code == 200
    assert api.put(url, json={"value": 0.4}, params={"token": "s3cret"}).status_code == 200
    assert api.get("/api/status").json()["authorised"] is False  # reading needs no token
    assert station.estimators["dcm"].gains["kp_rp"] == 0.4
    refused = [e.data for e in station.events.recent if e.kind == "refused"]
    assert refused == [{"reason": "token", "path": url, "user_agent": "testclient"}] * 2  # each in the audit log
    assert api.put(url, json={"value": 0.3}, params={"token": "sécret"}).status_code == 401  # not a 500
    # JSON only as JSON: a text/plain body (a form or no-cors post needs no preflight) is refused even
    # with the token (fastapi >= 0.132 checks the Content-Type: the floor in pyproject.toml)
    plain = api.put(url, content=b'{"value": 0.3}', headers={"content-type": "text/plain", TOKEN_HEADER: TOKEN})
    assert plain.status_code == 422 and station.estimators["dcm"].gains["kp_rp"] == 0.4


def test_the_startup_url_trades_the_token_for_a_strict_cookie(station: FakeStation):
    api = TestClient(create_app(station, token=TOKEN), base_url="http://127.0.0.1:8000")  # type: ignore[arg-type]
    opened = api.get("/", params={"token": TOKEN}, follow_redirects=False)
    assert opened.status_code == 303 and opened.headers["location"] == "/"  # the token leaves the address bar
    cookie = opened.headers["set-cookie"]
    assert cookie.startswith(f"gcs_token_8000={TOKEN};")  # per port: two servers on one host keep their own
    assert "HttpOnly" in cookie and "SameSite=strict" in cookie and "Path=/" in cookie
    assert api.get("/api/status").json()["authorised"] is True  # the cookie is the page's credential
    url = "/api/estimators/dcm/gains/kp_rp"
    assert api.put(url, json={"value": 0.3}).status_code == 200
    other_port = TestClient(api.app, base_url="http://127.0.0.1:8010", cookies={"gcs_token_8000": TOKEN})
    assert other_port.put(url, json={"value": 0.4}).status_code == 401  # another server's cookie is not ours
    # the page's other parameters stay: a bookmark of vehicle 2's page opened the first vehicle's
    kept = api.get("/", params={"vehicle": "2", "token": TOKEN}, follow_redirects=False)
    assert kept.status_code == 303 and kept.headers["location"] == "/?vehicle=2", kept.headers["location"]

    fresh = TestClient(create_app(station, token=TOKEN), base_url="http://127.0.0.1:8000")  # type: ignore[arg-type]
    wrong = fresh.get("/", params={"token": "guess"}, follow_redirects=False)
    assert wrong.status_code == 303 and "set-cookie" not in wrong.headers  # opens read-only
    assert fresh.get("/api/status").json()["authorised"] is False
    assert station.events.recent[-1].kind == "refused" and station.events.recent[-1].data["path"] == "/"


def test_page_and_its_scripts_are_served_locally(api: TestClient):
    page = api.get("/")
    assert page.status_code == 200 and "/vendor/uplot/uPlot.iife.min.js" in page.text
    assert api.get("/vendor/uplot/uPlot.iife.min.js").status_code == 200
    assert '<script src="/colors.js">' in page.text
    colors = api.get("/colors.js")  # the plots' colours are the 3-D view's (gcs/server/colors.py)
    assert colors.headers["content-type"].startswith("text/javascript") and '"dcm": "#d62728"' in colors.text
    assert "/api/estimators/{name}/gains/{gain}" in api.get("/openapi.json").json()["paths"]


def test_points_reach_the_history(api: TestClient, station: FakeStation):
    points = [AttitudePoint(1.0, "dcm", 0.1, 0.2, 0.3), AttitudePoint(1.02, "dcm", 0.1, 0.2, 0.31)]
    with api:  # the points arrive on the app's event loop, as the station emits them
        api.portal.call(station.points.emit, points)
        history = api.get("/api/history", params={"seconds": 10}).json()["points"]
    t, roll, _, yaw = history["dcm"]
    assert t == [1.0, 1.02] and np.allclose(roll, np.degrees(0.1), atol=1e-3)  # degrees, 3 decimals
    assert np.isclose(yaw[-1], np.degrees(0.31), atol=1e-3)


def test_foreign_host_and_origin_are_refused_and_logged(station: FakeStation):
    api = client_of(station, allow_origins=("http://laptop.local:9000",))
    url = "/api/estimators/dcm/gains/kp_rp"
    # DNS rebinding: a foreign name that resolves to loopback
    rebound = api.put(url, json={"value": 0.3}, headers={"Host": "evil.example:8000"})
    assert rebound.status_code == 403 and "Host" in rebound.text
    assert api.get("/api/status", headers={"Host": "evil.example"}).status_code == 403
    # another page's scripts, whatever the content type
    for origin in ("http://evil.example", "http://127.0.0.1:9999", "null"):
        for body in (
            {"json": {"value": 0.3}},
            {"content": b'{"value": 0.3}', "headers": {"content-type": "text/plain"}},
        ):
            headers = {**body.pop("headers", {}), "Origin": origin} if "headers" in body else {"Origin": origin}
            refused = api.put(url, headers=headers, **body)
            assert refused.status_code == 403 and "origin" in refused.text
    assert station.estimators["dcm"].gains["kp_rp"] == 0.2  # nothing changed
    refusals = [e for e in station.events.recent if e.kind == "refused"]
    assert {e.data["origin"] for e in refusals} >= {"http://evil.example", "http://127.0.0.1:9999", "null"}
    assert {e.data["reason"] for e in refusals} == {"host", "origin"} and refusals[0].data["path"] == url
    # the page's own origin, the allowed one, and a client that sends none (curl, scripts)
    assert api.put(url, json={"value": 0.3}, headers={"Origin": "http://127.0.0.1"}).status_code == 200
    assert api.put(url, json={"value": 0.4}, headers={"Origin": "http://laptop.local:9000"}).status_code == 200
    assert api.put(url, json={"value": 0.5}).status_code == 200
    assert station.estimators["dcm"].gains["kp_rp"] == 0.5


def test_every_response_forbids_framing_and_sniffing(api: TestClient):
    for path in ("/", "/api/status", "/api/nope"):
        headers = api.get(path).headers
        assert headers["x-frame-options"] == "DENY" and "frame-ancestors 'none'" in headers["content-security-policy"]
        assert headers["x-content-type-options"] == "nosniff" and headers["referrer-policy"] == "no-referrer"
    assert api.get("/docs").status_code == 404 and api.get("/redoc").status_code == 404  # they load a CDN


def test_large_bodies_are_refused_with_413(api: TestClient, station: FakeStation):
    url = "/api/estimators/dcm/gains/kp_rp"
    big = b'{"value": 0.3, "pad": "' + b"x" * (MAX_BODY + 1) + b'"}'
    assert api.put(url, content=big, headers={"content-type": "application/json"}).status_code == 413

    def chunks():
        yield b'{"value": 0.3, "pad": "'
        for _ in range(100):
            yield b"x" * 1024
        yield b'"}'

    assert api.put(url, content=chunks(), headers={"content-type": "application/json"}).status_code == 413
    assert station.estimators["dcm"].gains["kp_rp"] == 0.2
    assert [e.data["reason"] for e in station.events.recent if e.kind == "refused"] == ["size", "size"]


def test_expensive_requests_are_limited_per_client(api: TestClient, station: FakeStation):
    """What-if, export, replay and parameter downloads cost seconds of work each: past a burst, a
    client gets 429 with Retry-After (and an audit entry) before any work is queued."""
    codes = [
        api.post("/api/whatif", json={"source": "nope", "estimator": "dcm", "gains": {}}).status_code for _ in range(6)
    ]
    assert codes == [404] * 4 + [429] * 2  # the burst reaches the handler (no such session), then refused
    refused = api.post("/api/whatif", json={"source": "nope", "estimator": "dcm", "gains": {}})
    assert 1 <= int(refused.headers["retry-after"]) <= 6 and "a minute" in refused.json()["detail"]
    assert api.get("/api/sessions/nope/export").status_code == 404  # each endpoint has its own bucket
    rate = [e for e in station.events.recent if e.kind == "refused" and e.data["reason"] == "rate"]
    assert len(rate) == 3 and rate[0].data["path"] == "/api/whatif" and rate[0].client == "api:testclient"


def test_a_rate_limit_refills_and_keeps_clients_apart():
    limit = RateLimit("export", per_minute=30, burst=2)
    assert [limit.take("a", 0.0), limit.take("a", 0.0)] == [0.0, 0.0]
    assert limit.take("a", 0.0) == pytest.approx(2.0)  # one request refills in 60/30 s
    assert limit.take("b", 0.0) == 0.0  # another client has its own bucket
    assert limit.take("a", 2.0) == 0.0  # refilled
    for k in range(5000):  # spoofed addresses do not grow memory without bound
        limit.take(f"10.0.{k // 256}.{k % 256}", 3.0)
    assert len(limit._buckets) <= MAX_CLIENTS
