"""The 3-D view's server (viser, in a thread of its own) runs its event loop on uvloop, as the
station's loop does: its per-viewer windows were ~3 % of a core with 5 viewers on asyncio's own
loop (docs/benchmarks.md). asyncio is left as it was."""

from __future__ import annotations

import asyncio
import threading

import uvloop
import viser
from conftest import free_port
from websockets.sync.client import connect

from bench.viser_clients import camera_message
from gcs.server.scene import LocalViserServer


def test_the_3d_views_server_runs_its_loop_on_uvloop_and_leaves_asyncio_as_it_was():
    policy, new_event_loop = asyncio.get_event_loop_policy(), asyncio.new_event_loop
    port = free_port()
    server = LocalViserServer("127.0.0.1", port)
    loops: list[type] = []
    connected = threading.Event()

    async def on_connect(_client: viser.ClientHandle) -> None:  # awaited on viser's loop
        loops.append(type(asyncio.get_running_loop()))
        connected.set()

    server.on_client_connect(on_connect)
    try:
        with connect(f"ws://127.0.0.1:{port}", subprotocols=[f"viser-v{viser.__version__}"], max_size=None) as ws:
            ws.send(camera_message())  # a viewer counts as connected once it says where it looks
            assert connected.wait(30), "viser never saw the client connect"
    finally:
        server.stop()
    assert loops == [uvloop.Loop]
    assert asyncio.get_event_loop_policy() is policy
    assert asyncio.new_event_loop is new_event_loop
    loop = asyncio.new_event_loop()  # as the station's other threads make theirs: asyncio's default
    assert type(loop) is not uvloop.Loop
    loop.close()
