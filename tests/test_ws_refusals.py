"""A WebSocket refused at its handshake says why, as a refused request does: the status and the
one-line reason come back as an HTTP response to the handshake (ASGI's denial response). Real
server (the dashboard's uvicorn, the shipped protocol), real WebSocket and HTTP clients."""

from __future__ import annotations

import asyncio

import httpx
import websockets
from live import running_station

from gcs.server.dashboard import DashboardServer


async def refusals(udp_port: int) -> dict[str, tuple[int, str]]:
    """{what: (status, body)} of each refused handshake and request, and "live" for /ws/live."""
    got: dict[str, tuple[int, str]] = {}
    async with running_station(f"udpin:127.0.0.1:{udp_port}", request_streams=False) as station:
        server = DashboardServer(station, port=0, viser=False)
        await server.start()
        base = f"127.0.0.1:{server.port}"
        try:
            async with websockets.connect(f"ws://{base}/ws/live") as ws:
                got["live"] = (101, ws.request.path if ws.request else "")
            for what, path, headers in (
                ("ws sysid", "/api/vehicles/abc/ws/live", {}),
                ("ws origin", "/ws/live", {"Origin": "http://evil.example"}),
            ):
                try:
                    async with websockets.connect(f"ws://{base}{path}", additional_headers=headers):
                        got[what] = (101, "")
                except websockets.InvalidStatus as refused:
                    got[what] = (refused.response.status_code, refused.response.body.decode())
            async with httpx.AsyncClient(base_url=f"http://{base}") as api:
                for what, path, headers in (
                    ("rest sysid", "/api/vehicles/abc/status", {}),
                    ("rest origin", "/api/status", {"Origin": "http://evil.example"}),
                ):
                    answer = await api.get(path, headers=headers)
                    got[what] = (answer.status_code, answer.text)
        finally:
            await server.stop()
    return got


def test_refused_websocket_says_why_as_rest_does(udp_port):
    got = asyncio.run(refusals(udp_port))
    assert got["live"] == (101, "/ws/live")
    # a sysid that is no number: 422 and the reason, at the handshake as over REST (it was a bare
    # 403 at the handshake, and REST's was "Not Found")
    status, reason = got["ws sysid"]
    assert status == 422 and "sysid 'abc' is not a number" in reason, got
    assert got["rest sysid"] == got["ws sysid"], got
    # the guard's refusal of another page's origin: 403 with its reason (the handshake's had none)
    status, reason = got["ws origin"]
    assert status == 403 and "another web page's origin" in reason, got
    assert got["rest origin"] == got["ws origin"], got
