"""What keeps the event loop answering quickly while it serves (docs/benchmarks.md, issue 17):
the start-up heap frozen out of the collector's walk while a station serves, and handed back
when it stops; the status body encoded once per published snapshot, as it is published;
the station's priority raised when the system permits it, and left with a reason when not;
connections that write without waiting for the client's delayed ACK; the recording's first flush
importing nothing; an estimation backlog worked off in slices."""

from __future__ import annotations

import asyncio
import gc
import os
import socket
import subprocess
import sys

import httpx
import websockets
from live import dashboard, running_station, wait_for

from gcs.core import strict_json
from gcs.mavlink.dialect import Encoder, mavlink
from gcs.runtime.estimation import BATCH
from gcs.runtime.station import Station, StationConfig
from gcs.server.status_body import PER_REQUEST


def test_start_up_heap_frozen_while_serving(udp_port):
    async def run() -> tuple[int, int, int, int]:
        gc.unfreeze()  # whatever an earlier test left
        station = Station(StationConfig(connect=f"udpin:127.0.0.1:{udp_port}", request_streams=False))
        await station.start()
        try:
            # the estimators' kernels load in a thread, then everything alive is frozen
            await wait_for(lambda: gc.get_freeze_count() > 0, 120, "the estimators warmed and froze the heap")
            with_station = gc.get_freeze_count()
            async with dashboard(station, viser=False):
                with_server = gc.get_freeze_count()
                walked = len(gc.get_objects())  # what a full collection walks now
            after_server = gc.get_freeze_count()
        finally:
            await station.stop()
        return with_station, with_server, walked, after_server + gc.get_freeze_count()

    with_station, with_server, walked, after_stop = asyncio.run(run())
    assert with_server > with_station > 0
    # a full pass walks a small part of the process: the start-up objects are frozen
    assert walked < with_server / 4, (walked, with_server)
    assert after_stop == 0  # handed back: a stopped station's cycles are collected again


def test_status_encoded_once_per_snapshot_as_it_is_published(udp_port):
    asyncio.run(status_per_snapshot(udp_port))


async def status_per_snapshot(udp_port: int) -> None:
    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    encoder = Encoder(1, 1)

    heartbeat = mavlink.MAVLink_heartbeat_message(2, 3, 81, 0, 4, 3)

    def heartbeats(n: int) -> None:
        for _ in range(n):
            vehicle.sendto(encoder.encode(heartbeat), ("127.0.0.1", udp_port))

    async with (
        running_station(f"udpin:127.0.0.1:{udp_port}", request_streams=False, estimate=False) as station,
        dashboard(station, viser=False) as server,
        httpx.AsyncClient(base_url=f"http://127.0.0.1:{server.port}") as http,
    ):
        bodies = server._server.config.app.state.status_bodies
        heartbeats(3)
        await wait_for(lambda: station.link.stats.framing.packets >= 3, 10, "the heartbeats")
        for _ in range(20):  # two requests between two publishes (one a second): retried if one fell between
            before = bodies.encoded
            station.publish()
            snap = station.snapshot
            # encoded in the loop's turn after the publish, before any request
            await wait_for(lambda: bodies.encoded > before, 10, "the snapshot encoded")  # noqa: B023
            encoded = bodies.encoded
            anonymous = strict_json.loads((await http.get("/api/status")).content)
            authorised = strict_json.loads((await http.get("/api/status", headers=server.auth_headers)).content)
            if station.snapshot is snap and encoded == before + 1:  # no other publish in between
                break
        assert station.snapshot is snap
        assert encoded == before + 1
        assert bodies.encoded == encoded  # by neither request
        assert not anonymous["authorised"] and authorised["authorised"]  # each request's own fields
        shared = {k: v for k, v in anonymous.items() if k not in PER_REQUEST}
        assert shared == {k: v for k, v in authorised.items() if k not in PER_REQUEST}
        assert shared["link"]["packets"] == snap.link.stats.packets >= 3

        heartbeats(2)  # the link's counters move; the next snapshot carries them
        await wait_for(lambda: station.link.stats.framing.packets >= snap.link.stats.packets + 2, 10, "the heartbeats")
        station.publish()
        after = strict_json.loads((await http.get("/api/status")).content)
        assert after["link"]["packets"] == station.snapshot.link.stats.packets >= shared["link"]["packets"] + 2
        assert set(after) == set(anonymous)
    vehicle.close()


RAISE = (
    "import os; from gcs.runtime.priority import raise_priority; "
    "line = raise_priority(-5); print(os.getpriority(os.PRIO_PROCESS, 0), line)"
)


def priority_child(*wrapper: str) -> tuple[int, str]:
    out = subprocess.run([*wrapper, sys.executable, "-c", RAISE], capture_output=True, text=True, check=True).stdout
    nice, line = out.strip().split(" ", 1)
    return int(nice), line


def test_priority_raised_when_permitted_and_left_with_a_reason_when_not():
    # not permitted: no CAP_SYS_NICE (dropped when running as root) and a RLIMIT_NICE allowing nothing
    drop = ["setpriv", "--inh-caps=-sys_nice", "--bounding-set=-sys_nice"] if os.geteuid() == 0 else []
    nice, line = priority_child("prlimit", "--nice=0", *drop)
    assert nice == 0, line
    assert "not permitted" in line and "limits.conf" in line, line
    if os.geteuid() == 0:  # permitted (CAP_SYS_NICE): the station runs ahead of ordinary programs
        nice, line = priority_child()
        assert nice == -5 and "raised from 0" in line, line


def test_connections_send_without_nagle(udp_port):
    """Every accepted connection (a page's keep-alive requests, its /ws/live) writes at once: with
    Nagle's algorithm on, a write behind an unacknowledged one waited for the client's delayed ACK
    (40 ms on Linux), per request and per live frame."""

    async def run() -> list[int]:
        async with (
            running_station(f"udpin:127.0.0.1:{udp_port}", request_streams=False, estimate=False) as station,
            dashboard(station, viser=False) as server,
            httpx.AsyncClient(base_url=f"http://127.0.0.1:{server.port}") as http,
            websockets.connect(f"ws://127.0.0.1:{server.port}/ws/live") as ws,
        ):
            await ws.recv()  # hello
            assert (await http.get("/api/status")).status_code == 200
            connections = server._server.server_state.connections
            await wait_for(lambda: len(connections) == 2, 10, "the page's two connections")
            return [
                c.transport.get_extra_info("socket").getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY)
                for c in connections
            ]

    assert all(asyncio.run(run()))


FIRST_FLUSH = """
import asyncio, sys, tempfile
from gcs.runtime.station import Station, StationConfig
from gcs.sessions import columnar
from gcs.transport.address import free_port

async def main():
    root = tempfile.mkdtemp()
    config = StationConfig(connect=f"udpin:127.0.0.1:{free_port()}", sessions_dir=root, record=True, estimate=False)
    station = Station(config)
    await station.start()
    before = set(sys.modules)
    columnar.StreamEncoder(columnar.ATTITUDE_SCHEMA).encode([(1.0, 0.5, "dcm", 0.1, 0.2, 0.3)])
    print(sorted(set(sys.modules) - before))
    await station.stop()

asyncio.run(main())
"""


def test_recording_writer_imports_nothing_at_its_first_flush():
    """pyarrow's first conversion imports pandas (0.7 s holding the GIL): a recording station has
    it done when it starts, not by the writer thread with the link and the pages live."""
    out = subprocess.run([sys.executable, "-c", FIRST_FLUSH], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]", out


def test_estimation_backlog_worked_off_in_slices(udp_port):
    """A burst of IMU packets (as after the process waited for a core) is estimated a slice per
    turn of the event loop, so everything else on the loop runs between the slices."""

    async def run() -> tuple[int, list[int]]:
        async with running_station(f"udpin:127.0.0.1:{udp_port}", request_streams=False) as station:
            estimation = station.estimation
            vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            encoder = Encoder(1, 1)

            def imu(k: int) -> bytes:
                return encoder.encode(
                    mavlink.MAVLink_highres_imu_message(
                        1000 + 2500 * k, 0.1, 0.0, -9.8, 0.0, 0.0, 0.0, 0.2, 0.0, 0.4, 1000.0, 0, 0, 25.0, 0x1FFF, 0
                    )
                )

            def fed_after_one_more() -> bool:  # the first may come before the socket is bound
                vehicle.sendto(imu(0), ("127.0.0.1", udp_port))
                return estimation.messages_fed >= 1

            await wait_for(fed_after_one_more, 120, "the estimators warmed and fed")
            fed_per_turn: list[int] = []
            last = [estimation.messages_fed]
            loop = asyncio.get_running_loop()

            def each_turn() -> None:  # runs once per iteration of the loop, until the burst is in
                fed_per_turn.append(estimation.messages_fed - last[0])
                last[0] = estimation.messages_fed
                if last[0] < start + burst:
                    loop.call_soon(each_turn)

            burst, start = 300, estimation.messages_fed
            loop.call_soon(each_turn)
            for k in range(1, burst + 1):  # all in the socket before the loop runs again
                vehicle.sendto(imu(k), ("127.0.0.1", udp_port))
            await wait_for(lambda: estimation.messages_fed >= start + burst, 30, "the burst estimated")
            vehicle.close()
            return burst, fed_per_turn

    burst, fed_per_turn = asyncio.run(run())
    assert sum(fed_per_turn) >= burst
    assert max(fed_per_turn) <= BATCH, fed_per_turn
