"""Run the dashboard next to a Station in the current event loop: uvicorn serving the
FastAPI app, viser (its own thread and port, same host) with the pose view and gain panel, and
the pose view's refresh (gcs.server.pose_refresh). `gcs serve`, `gcs demo`, the tests and the
benchmarks all use this."""

from __future__ import annotations

import asyncio
import secrets
import socket
from typing import TYPE_CHECKING

import uvicorn

from gcs.runtime import heap
from gcs.runtime.facade import FleetFacade, StationFacade
from gcs.server.addresses import local_host, shared_hosts, url_host
from gcs.server.app import create_app, record_refusal
from gcs.server.deps import TOKEN_HEADER
from gcs.server.guard import FrontDoor, Refusal
from gcs.server.live import LiveHub
from gcs.server.uvicorn_server import DashboardUvicorn
from gcs.server.ws_direct import DirectFrameProtocol
from gcs.sessions.workbench import warm_up

if TYPE_CHECKING:
    from viser import ViserServer

    from gcs.server.fleet_scene import FleetScene
    from gcs.server.pose_refresh import PoseRefresh

#: Pose view refresh at most, Hz (the eye does not need the 200 Hz the plots get).
POSE_HZ = 30.0


class DashboardServer:
    """Start with `await start()`, stop with `await stop()`. port=0 picks a free port; the ports
    actually bound are `port` and `viser_port` after start (viser silently moves to the next
    free port when its own is taken, so it is always read back)."""

    def __init__(
        self,
        station: StationFacade,
        host: str = "127.0.0.1",
        port: int = 8000,
        *,
        viser_port: int | None = None,
        viser: bool = True,
        hub: LiveHub | None = None,
        send_buffer: int = 256 * 1024,
        allow_origins: tuple[str, ...] = (),
        token: str | None = None,
        fleet: FleetFacade | None = None,
        ws_protocol: str = "direct",
    ) -> None:
        self.station = station
        self.fleet = fleet
        self.host = host
        self.port = port
        self.viser_port = viser_port
        self.use_viser = viser
        self.hub = hub or LiveHub()
        self.send_buffer = send_buffer
        self.ws_protocol = ws_protocol
        self.allow_origins = allow_origins
        self.token = token or secrets.token_urlsafe(16)
        self.viser: ViserServer | None = None
        self._server: uvicorn.Server | None = None
        self._tasks: list[asyncio.Task] = []

    @property
    def url(self) -> str:
        """The start-up URL on this machine: opening it gives the browser the token (as a cookie)."""
        return self._url(local_host(self.host))

    @property
    def shared_urls(self) -> list[str]:
        """Bound to every interface: the start-up URL at each address other machines reach."""
        return [self._url(host) for host in shared_hosts(self.host)]

    def _url(self, host: str) -> str:
        return f"http://{url_host(host)}:{self.port}/?token={self.token}"

    @property
    def auth_headers(self) -> dict[str, str]:
        """What a script sends with a change."""
        return {TOKEN_HEADER: self.token}

    async def start(self) -> None:
        # IPPROTO_TCP named, not left 0: asyncio turns Nagle's algorithm off (TCP_NODELAY) only on
        # sockets whose proto says TCP, and the accepted ones inherit it. With Nagle on, a response's
        # body or a live frame written while the previous write was unacknowledged waited for the
        # client's delayed ACK: 44 ms per keep-alive request instead of 0.3 (docs/benchmarks.md).
        sock = socket.socket(
            socket.AF_INET6 if ":" in self.host else socket.AF_INET, socket.SOCK_STREAM, socket.IPPROTO_TCP
        )
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        # Inherited by every accepted connection: caps the kernel memory a viewer that stops
        # reading can hold, and makes its back-pressure reach its queue (and drop counter) in
        # seconds instead of minutes of send-buffer autotuning.
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, self.send_buffer)
        try:
            sock.bind((self.host, self.port))  # bound here so a taken port fails now, with its number
        except OSError as exc:
            sock.close()
            where = f"cannot serve the dashboard on {self.host}:{self.port} (--port): {exc.strerror}"
            raise OSError(exc.errno, where) from None
        # listening before viser starts: viser moves to the next port when its own is taken, and
        # a port only bound (SO_REUSEADDR) looked free to it. uvicorn's listen() sets the backlog.
        sock.listen()
        self.port = sock.getsockname()[1]
        app = create_app(
            self.station,
            self.hub,
            token=self.token,
            bound_host=self.host,
            allow_origins=self.allow_origins,
            fleet=self.fleet,
        )
        if self.use_viser:
            self._start_viser()
            app.state.viser_port = self.viser_port
        # no permessage-deflate: the live frames are small and frequent, and compressing each one
        # for each client cost the loop more CPU than the bytes it saved (docs/benchmarks.md)
        # "direct": uvicorn's sans-I/O protocol with /ws/live's direct writes (gcs.server.ws_direct);
        # else one of uvicorn's own ("auto", "websockets-sansio", "websockets", "wsproto")
        ws = DirectFrameProtocol if self.ws_protocol == "direct" else self.ws_protocol
        config = uvicorn.Config(app, log_level="warning", ws=ws, ws_ping_interval=None, ws_per_message_deflate=False)
        self._server = DashboardUvicorn(config)
        self._tasks.append(asyncio.create_task(self._server.serve(sockets=[sock])))
        while not self._server.started:
            if self._tasks[0].done():
                self._tasks[0].result()  # raises why uvicorn did not start
            await asyncio.sleep(0.01)
        if self.viser is not None:
            self._tasks.append(asyncio.create_task(self.pose_refresh.run()))
        self._tasks.append(asyncio.create_task(self.station.in_worker(warm_up), name="gcs:warm-worker"))
        heap.freeze()  # the app, uvicorn and viser: no full collection walks them again

    def _start_viser(self) -> None:
        from gcs.server.fleet_scene import FleetScene  # noqa: PLC0415 - imports viser
        from gcs.server.pose_refresh import PoseRefresh  # noqa: PLC0415 - imports viser
        from gcs.server.scene import LocalViserServer  # noqa: PLC0415

        loop = asyncio.get_running_loop()

        def refused(refusal: Refusal) -> None:  # told on viser's thread; the event log is the loop's
            loop.call_soon_threadsafe(record_refusal, self.station, refusal)

        door = FrontDoor.of(self.host, self.allow_origins, framed=True)  # the page frames its view
        server = LocalViserServer(self.host, self.viser_port or self.port + 1, door, refused)
        self.viser = server
        self.viser_port = server.get_port()
        self.scene: FleetScene = FleetScene(server, self.station, self.fleet)
        self.pose_refresh: PoseRefresh = PoseRefresh(server, self.scene, POSE_HZ)

    async def stop(self) -> None:
        if self._server is not None:
            self._server.should_exit = True
        for task in self._tasks[1:]:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks = []
        if self.viser is not None:
            self.viser.stop()
            self.viser = None
        heap.release()
