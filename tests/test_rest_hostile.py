"""Hostile values in requests get a 4xx with a strict JSON answer, never a 500: NaN, Infinity,
numbers beyond float64 or float32, lone surrogates, wrong fields. FastAPI's own validation answer
quotes the input, which is where NaN and surrogates used to turn a 422 into a 500. Real server
under uvicorn, no vehicle (the tuning routes wait for one: not here); the token is sent
whenever the server has one."""

from __future__ import annotations

import asyncio
import shutil

import httpx
from live import running_station

from gcs.core.strict_json import loads as strict_loads
from gcs.server.dashboard import DashboardServer

NUMBERS = ["NaN", "Infinity", "-Infinity", "1e400", "3.5e38", '"x"', "null"]
REQUESTS = [
    *(("PUT", "/api/estimators/dcm/gains/kp_rp", f'{{"value": {v}}}') for v in NUMBERS),
    ("GET", "/api/replay?source=x", None),
    ("GET", "/api/replay?source=%ED%A0%80", None),
    ("POST", "/api/whatif", '{"source": "x", "estimator": "dcm", "gains": {"kp_rp": NaN}}'),
    ("POST", "/api/recording/note", '{"text": "\\ud800"}'),
    ("POST", "/api/recording/note", '{"note": "\\ud800", "x": NaN}'),
    ("POST", "/api/estimators/dcm/preset", '{"preset": "\\u0000\\ud800"}'),
    ("GET", "/api/history?seconds=nan", None),
    ("GET", "/api/history?seconds=inf", None),
    ("GET", "/api/history?seconds=1e400", None),
    *(("GET", f"/api/replay?source=fragment.bin&gain=dcm.kp_rp={v}", None) for v in ("nan", "inf", "1e400", "x")),
    ("GET", "/api/replay?source=fragment.bin&estimator=nope", None),
]


def test_hostile_request_values_get_a_strict_4xx(udp_port, tmp_path, logs_dir):
    shutil.copy(logs_dir / "ardupilot-fragment.bin", tmp_path / "fragment.bin")  # a source to replay
    answers = asyncio.run(scenario(udp_port, tmp_path, REQUESTS))
    for (method, path, body), (code, text) in zip(REQUESTS, answers, strict=True):
        assert 400 <= code < 500, (method, path, body, code, text)
        strict_loads(text)  # raises on NaN/Infinity tokens


def _kp_rp(answer: tuple[int, str]) -> float:
    """kp_rp in a GET /api/estimators/dcm answer."""
    return next(g["value"] for g in strict_loads(answer[1])["gains"] if g["name"] == "kp_rp")


def test_a_body_of_the_wrong_type_or_with_a_misspelt_field_is_refused_and_changes_nothing(udp_port, tmp_path):
    """`true` is no gain value and `"0.3"` no number; `{"name": ...}` is no preset request. Each
    was taken: kp_rp became 1.0, and the misspelt key reset dcm to its default preset, both 200."""
    gain, preset, read = "/api/estimators/dcm/gains/kp_rp", "/api/estimators/dcm/preset", "/api/estimators/dcm"
    refused = [
        ("PUT", gain, '{"value": true}', "value"),
        ("PUT", gain, '{"value": "0.3"}', "value"),
        ("PUT", gain, '{"value": 0.4, "estimator": "kf"}', "estimator"),
        ("POST", preset, '{"name": "seed000"}', "name"),
    ]
    requests = [
        ("PUT", gain, '{"value": 1}', None),  # an integer is a number: taken
        ("PUT", gain, '{"value": 0.3}', None),
        *refused,
        ("GET", read, None, None),
    ]
    answers = asyncio.run(scenario(udp_port, tmp_path, [r[:3] for r in requests]))
    assert [code for code, _ in answers[:2]] == [200, 200], answers[:2]
    for (method, path, body, field), (code, text) in zip(refused, answers[2:-1], strict=True):
        assert code == 422, (method, path, body, code, text)
        assert [e["loc"] for e in strict_loads(text)["detail"]] == [["body", field]], text
    assert _kp_rp(answers[-1]) == 0.3


async def scenario(udp_port: int, tmp_path, requests) -> list[tuple[int, str]]:
    async with running_station(f"udpin:127.0.0.1:{udp_port}", sessions_dir=str(tmp_path), record=True) as station:
        server = DashboardServer(station, port=0, viser=False)
        await server.start()
        headers = {"Content-Type": "application/json"}
        if server.token:
            headers["X-GCS-Token"] = server.token
        try:
            async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{server.port}", timeout=30) as api:
                answers = []
                for method, path, body in requests:
                    response = await api.request(method, path, content=body, headers=headers)
                    answers.append((response.status_code, response.text))
                return answers
        finally:
            await server.stop()
