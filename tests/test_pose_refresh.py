"""The 3-D view is drawn only while someone watches it (gcs.server.pose_refresh), and a viewer
that connects later still sees the vehicle's current pose: what arrived while nobody watched is
drawn as soon as it connects, and what arrives while it watches follows. The viewer is a real
viser client on viser's real WebSocket (its wire format: zstd-compressed msgpack), fed by the
station from ATTITUDE messages on a real UDP socket."""

from __future__ import annotations

import asyncio
import math
import socket

import msgspec
import viser
import websockets
import zstandard
from conftest import free_port
from live import dashboard, running_station

from bench.viser_clients import camera_message
from gcs.core.rotation import euler_to_quat
from gcs.mavlink.dialect import Encoder, mavlink
from gcs.runtime.signal import Signal
from gcs.server.pose_refresh import PoseRefresh
from gcs.server.scene import PoseView, display_wxyz, turned

ONBOARD = "/vehicle0/onboard"
#: two attitudes (roll, pitch, yaw in degrees), far from the level pose the view starts with
FIRST, SECOND = (20.0, -10.0, 120.0), (-15.0, 25.0, -60.0)


def attitude(encoder: Encoder, pose: tuple[float, float, float], time_boot_ms: int) -> bytes:
    roll, pitch, yaw = (math.radians(a) for a in pose)
    return encoder.encode(mavlink.MAVLink_attitude_message(time_boot_ms, roll, pitch, yaw, 0.0, 0.0, 0.0))


def shown(pose: tuple[float, float, float]) -> tuple[float, float, float, float]:
    return display_wxyz(euler_to_quat(*(math.radians(a) for a in pose)))


class ViserViewer:
    """A viser client: announces its camera (viser counts a client as connected from then on) and
    keeps the orientations the server sends for ONBOARD, in order."""

    def __init__(self, ws: websockets.ClientConnection) -> None:
        self.ws = ws
        self.onboard: list[tuple[float, float, float, float]] = []
        self.changed = asyncio.Event()
        self._unzip = zstandard.ZstdDecompressor()

    async def connect(self) -> None:
        await self.ws.send(camera_message())

    async def read(self) -> None:
        async for frame in self.ws:
            assert isinstance(frame, bytes)
            size, packed = int.from_bytes(frame[:8], "little"), int.from_bytes(frame[8:16], "little")
            inner = msgspec.msgpack.decode(self._unzip.decompress(frame[16 : 16 + packed], max_output_size=size))
            for message in inner["messages"]:
                if message["type"] == "SetOrientationMessage" and message["name"] == ONBOARD:
                    self.onboard.append(tuple(message["wxyz"]))
                    self.changed.set()

    async def until_shown(self, pose: tuple[float, float, float], timeout: float) -> None:
        """Until the last orientation received for ONBOARD is `pose` as drawn."""
        async with asyncio.timeout(timeout):
            while not (self.onboard and turned(self.onboard[-1], shown(pose)) <= PoseView.MIN_TURN):
                self.changed.clear()
                await self.changed.wait()


def test_a_viewer_connecting_later_sees_the_current_pose(udp_port):
    async def go() -> None:
        encoder = Encoder(1, 1)
        async with (
            running_station(f"udpin:127.0.0.1:{udp_port}") as station,
            dashboard(station, viser_port=free_port(socket.SOCK_STREAM)) as server,
        ):

            def onboard_is(pose: tuple[float, float, float]) -> bool:
                point = station.latest_attitudes()[0].get("onboard")
                if point is None:
                    return False
                return turned(display_wxyz(euler_to_quat(point.roll, point.pitch, point.yaw)), shown(pose)) < 1e-4

            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as vehicle:
                # sent until the station's socket is open and it came (its kernels may compile first: ~60 s)
                async with asyncio.timeout(180):
                    k = 0
                    while not onboard_is(FIRST):
                        vehicle.sendto(attitude(encoder, FIRST, 1000 + 50 * k), ("127.0.0.1", udp_port))
                        k += 1
                        await asyncio.sleep(0.05)  # the vehicle's pace
                # nobody watches: nothing drawn, the view still at its level start
                assert server.pose_refresh.drawn == 0
                assert turned(tuple(server.scene.views[0].pose.onboard.wxyz), shown((0.0, 0.0, 0.0))) < 1e-9

                uri = f"ws://127.0.0.1:{server.viser_port}"
                async with websockets.connect(uri, subprotocols=[f"viser-v{viser.__version__}"], max_size=None) as ws:
                    viewer = ViserViewer(ws)
                    reading = asyncio.create_task(viewer.read())
                    try:
                        await viewer.connect()
                        # no attitude arrives after it connected: it is shown the one that came before
                        await viewer.until_shown(FIRST, 30)
                        vehicle.sendto(attitude(encoder, SECOND, 1000 + 50 * k), ("127.0.0.1", udp_port))
                        await viewer.until_shown(SECOND, 30)  # and follows what arrives while it watches
                    finally:
                        reading.cancel()
                        await asyncio.gather(reading, return_exceptions=True)

    asyncio.run(go())


class TurnLoop(asyncio.SelectorEventLoop):
    """asyncio's loop on a clock the test moves, counting the timers set on it."""

    def __init__(self) -> None:
        super().__init__()
        self.now = 1000.0
        self.timers = 0

    def time(self) -> float:
        return self.now

    def call_at(self, when, callback, *args, context=None):  # type: ignore[no-untyped-def]
        self.timers += 1
        return super().call_at(when, callback, *args, context=context)


class Watched:
    """What PoseRefresh asks of viser's server (who watches), with `viewers` connected; viser
    itself is covered by test_a_viewer_connecting_later_sees_the_current_pose."""

    def __init__(self, viewers: int = 1) -> None:
        self.viewers = viewers

    def on_client_connect(self, callback) -> None:  # type: ignore[no-untyped-def]
        self.connect = callback

    def on_client_disconnect(self, callback) -> None:  # type: ignore[no-untyped-def]
        pass

    def get_clients(self) -> dict[int, object]:
        return {k: object() for k in range(self.viewers)}


class CountedScene:
    def __init__(self) -> None:
        self.arrived: Signal[[list]] = Signal()
        self.drawn_at: list[float] = []

    def update(self) -> None:
        self.drawn_at.append(asyncio.get_running_loop().time())


def test_attitudes_that_keep_coming_are_drawn_in_their_own_turns_with_no_timer():
    """Arrivals every 1.2 periods: each is drawn in its own turn and nothing sets a timer; an
    arrival sooner than a period after a drawing is drawn a period later if nothing follows it."""
    period = 1 / 30

    async def turns() -> None:
        for _ in range(5):
            await asyncio.sleep(0)

    async def go(loop: TurnLoop) -> tuple[list[float], list[float], int, list[float]]:
        scene = CountedScene()
        refresh = PoseRefresh(Watched(), scene, 30)  # type: ignore[arg-type]
        drawing = asyncio.create_task(refresh.run())
        refresh.server.connect(None)  # type: ignore[attr-defined]  # a viewer connects
        await turns()
        arrivals = []
        for _ in range(10):
            loop.now += 1.2 * period
            arrivals.append(loop.now)
            scene.arrived.emit([])
            await turns()
        drawn, timers = list(scene.drawn_at), loop.timers
        loop.now += 0.5 * period  # too soon after the last drawing, and nothing after it
        scene.arrived.emit([])
        loop.now = arrivals[-1] + 2 * period - 1e-6
        await turns()
        assert len(scene.drawn_at) == len(drawn)  # not yet: a period after the next may-draw time
        loop.now += 2e-6
        while len(scene.drawn_at) == len(drawn):  # the timer is due: the loop runs it
            await asyncio.sleep(0)
        drawing.cancel()
        return drawn, arrivals, timers, scene.drawn_at[len(drawn) :]

    with asyncio.Runner(loop_factory=TurnLoop) as runner:
        loop = runner.get_loop()
        drawn, arrivals, timers, late = runner.run(go(loop))  # type: ignore[arg-type]
    assert drawn[1:] == arrivals and timers == 0
    assert late == [arrivals[-1] + 2 * period + 1e-6]


def test_more_viewers_are_drawn_for_less_often_within_the_fan_out_budget():
    """Attitudes every 5 ms for 1 s: one viewer is drawn for at 30 Hz, five at 20 Hz (100
    viewer-windows a second), ten at 10 Hz; never two drawings closer than that."""

    async def go(loop: TurnLoop, viewers: int) -> list[float]:
        scene = CountedScene()
        refresh = PoseRefresh(Watched(viewers), scene, 30, windows_per_s=100)  # type: ignore[arg-type]
        drawing = asyncio.create_task(refresh.run())
        refresh.server.connect(None)  # type: ignore[attr-defined]
        for _ in range(200):
            loop.now += 0.005
            scene.arrived.emit([])
            for _ in range(5):
                await asyncio.sleep(0)
        drawing.cancel()
        return scene.drawn_at

    for viewers, hz in ((1, 30), (5, 20), (10, 10)):
        with asyncio.Runner(loop_factory=TurnLoop) as runner:
            drawn = runner.run(go(runner.get_loop(), viewers))  # type: ignore[arg-type]
        gaps = [b - a for a, b in zip(drawn, drawn[1:], strict=False)]
        assert min(gaps) >= 1 / hz - 1e-9, (viewers, min(gaps))
        assert abs(len(drawn) - hz) <= 2, (viewers, len(drawn))
