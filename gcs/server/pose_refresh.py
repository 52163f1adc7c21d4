"""When the 3-D view is redrawn: at most `hz` times a second, only while someone watches it (a
viser client is connected) and only once a new attitude arrived since the last drawing, in the
turn that brought it (no timer of its own while attitudes keep coming: a wake-up of the loop
costs 0.1-0.2 ms of CPU here, and it waited 1/hz after each drawing, ~30 wake-ups a second).

It was redrawn 30 times a second whether anyone watched or anything changed: with five pages
open and no 3-D view, 18 % of the loop's CPU at 20 msg/s (CPU-time profile), and `gcs serve`
went from 3.7 to 3.1 % of a core without it (docs/benchmarks.md, "`gcs serve` when little
arrives"). A viewer that connects sees the latest pose at once: viser replays the scene it holds
to it, and what arrived while nobody watched is drawn as soon as viser says it connected.

Every drawing is a window of messages viser's own thread encodes and sends to each viewer, at
~0.3 ms of CPU per viewer (its loop, websockets' send path, msgpack and zstd: 4.2 % of a core
for 5 viewers at 27 Hz on asyncio's loop, docs/benchmarks.md; less on uvloop, which it runs on
now, gcs.server.scene.LocalViserServer). Like the live hub's frames, the drawings keep that
fan-out within a budget, `windows_per_s` viewer-windows a second: 30 Hz for up to 3 viewers,
20 Hz for 5, 10 Hz for 10, at most: a drawing comes in the first turn that brings attitudes a
whole period after the last, so on the live hub's 15 ms turns it comes every 60 ms with 5 viewers,
~16.7 Hz, and every 45 ms with one (22 Hz)."""

from __future__ import annotations

import asyncio
import math

import viser

from gcs.core.estimation import AttitudePoint
from gcs.server.fleet_scene import FleetScene


class PoseRefresh:
    """Create on the event loop, then `await run()` (until cancelled)."""

    def __init__(self, server: viser.ViserServer, scene: FleetScene, hz: float, windows_per_s: float = 100.0) -> None:
        self.server, self.scene = server, scene
        self.shortest, self.windows_per_s = 1.0 / hz, windows_per_s
        #: seconds from one drawing to the next: `shortest`, longer with many viewers
        self.period = self.shortest
        #: attitudes arrived since the scene was last drawn
        self.fresh = True
        #: a viser client is connected
        self.watched = False
        #: drawings made (each a `FleetScene.update`)
        self.drawn = 0
        self._due = asyncio.Event()  # watched and fresh
        self._next = -math.inf  # loop time from which the next drawing may come
        self._late: asyncio.TimerHandle | None = None
        loop = self._loop = asyncio.get_running_loop()

        def viewers_changed(_client: viser.ClientHandle) -> None:  # viser's thread: hop to the loop
            loop.call_soon_threadsafe(self._viewers_changed)

        server.on_client_connect(viewers_changed)
        server.on_client_disconnect(viewers_changed)
        scene.arrived.connect(self._arrived)

    async def run(self) -> None:
        while True:
            await self._due.wait()
            self._due.clear()
            if self._late is not None:
                self._late.cancel()
                self._late = None
            self.fresh = False
            self.scene.update()
            self.drawn += 1
            self._next = self._loop.time() + self.period

    def _arrived(self, _points: list[AttitudePoint]) -> None:
        self.fresh = True
        if not self.watched:
            return
        if self._loop.time() >= self._next:
            self._due.set()
        elif self._late is None:
            # too soon: the next arrival draws it (attitudes come every few ms), or, if none
            # comes, this timer a period later
            self._late = self._loop.call_at(self._next + self.period, self._due.set)

    def _viewers_changed(self) -> None:
        viewers = len(self.server.get_clients())
        self.watched = viewers > 0
        self.period = max(self.shortest, viewers / self.windows_per_s)
        if self.watched and self.fresh:
            self._due.set()
