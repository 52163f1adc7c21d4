"""/ws/live's direct writes (gcs.server.ws_direct): the hub's frames framed once and written
straight to each client's socket. Real server under uvicorn, real WebSocket clients: a client
gets every point and control message, in order, whether the frames go direct (the shipped
protocol) or through ASGI (uvicorn's own protocol, which offers no direct write); a client whose
socket is full falls back to the queue (tests/test_ws_clients.py's stuck client)."""

from __future__ import annotations

import asyncio
import math

import pytest
import websockets
from live import running_station, wait_for
from websockets.frames import Frame, Opcode

from gcs.core.estimation import AttitudePoint
from gcs.server import wire
from gcs.server.dashboard import DashboardServer
from gcs.server.ws_direct import binary_frame

SOURCES = ("onboard", "dcm")
BATCHES = 40


@pytest.mark.parametrize("size", [0, 1, 125, 126, 127, 65535, 65536, 70000])
def test_binary_frame_is_what_the_websockets_library_writes(size):
    payload = bytes(range(256)) * (size // 256) + bytes(size % 256)
    assert binary_frame(payload) == Frame(Opcode.BINARY, payload).serialize(mask=False)


@pytest.mark.parametrize(("protocol", "direct"), [("direct", True), ("websockets-sansio", False)])
def test_points_and_messages_reach_the_page_whichever_way_they_are_written(udp_port, protocol, direct):
    got, feed = asyncio.run(scenario(udp_port, protocol))
    points = [f for f in got if isinstance(f, wire.PointsFrame)]
    messages = [f for f in got if isinstance(f, dict)]
    for source in SOURCES:
        series = [f.points[source] for f in points if source in f.points]  # (t, roll, pitch, yaw) columns
        times = [t for t_col, *_ in series for t in t_col]
        rolls = [r for _, r_col, *_ in series for r in r_col]
        assert times == [round(10.0 + k * 0.01, 6) for k in range(BATCHES)]
        assert rolls == pytest.approx(list(range(BATCHES)), abs=1e-3)
    assert [m["value"] for m in messages] == [float(BATCHES)]
    # the gain message came after every point offered before it
    assert got.index(messages[0]) == len(got) - 1
    assert feed["sent_messages"] >= 2
    if direct:
        assert feed["direct_writes"] == feed["sent_messages"]
    else:
        assert feed["direct_writes"] == 0


async def scenario(udp_port: int, protocol: str) -> tuple[list, dict]:
    async with running_station(f"udpin:127.0.0.1:{udp_port}", request_streams=False) as station:
        server = DashboardServer(station, port=0, viser=False, ws_protocol=protocol)
        await server.start()
        hub = server.hub
        got: list = []
        try:
            async with websockets.connect(f"ws://127.0.0.1:{server.port}/ws/live") as ws:
                assert '"hello"' in await asyncio.wait_for(ws.recv(), 10)
                await wait_for(lambda: any(f.writer is not None for f in hub.clients.values()), 10, "the feed attached")
                feed = next(iter(hub.clients.values()))
                for k in range(BATCHES):  # a frame each
                    frames = hub.frames_out
                    hub.on_points([AttitudePoint(10.0 + k * 0.01, s, math.radians(k), 0.0, 0.0) for s in SOURCES])
                    await wait_for(lambda: hub.frames_out > frames, 10, "the flush")  # noqa: B023
                hub.broadcast({"type": "gain", "value": float(BATCHES)})
                while not any(isinstance(f, dict) and f.get("type") == "gain" for f in got):
                    data = await asyncio.wait_for(ws.recv(), 10)
                    if isinstance(data, bytes):
                        got += wire.decode(data)
                counters = {"sent_messages": feed.sent_messages, "direct_writes": feed.direct_writes}
        finally:
            await server.stop()
    return got, counters
