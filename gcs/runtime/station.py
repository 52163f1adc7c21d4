"""The ground station's live core for one vehicle: link, forwarding outputs, vehicle state
and stream requests, run together in one event loop. `gcs status`, `gcs demo` and the
server all start one of these. Data flow and conventions: docs/design.md"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field

from gcs.mavlink.sampling import DECLINATION_PARAMS
from gcs.runtime.bus import MessageBus
from gcs.runtime.estimation import LiveEstimation
from gcs.runtime.events import EventLog
from gcs.runtime.forward import Output
from gcs.runtime.link import Link
from gcs.runtime.params import ParamClient
from gcs.runtime.recorder import SessionRecorder
from gcs.runtime.streams import StreamPlan, StreamRequester
from gcs.runtime.vehicle import VehicleState


@dataclass
class StationConfig:
    connect: str
    baud: int | str = 57600
    speed: float = 1.0
    outputs: list[str] = field(default_factory=list)
    heartbeat_timeout: float = 3.0
    plan: StreamPlan = field(default_factory=StreamPlan)
    request_streams: bool = True
    estimate: bool = True
    record_dir: str | None = None  # where sessions are recorded; None: no recording


class GroundStation:
    def __init__(self, config: StationConfig, bus: MessageBus | None = None) -> None:
        self.config = config
        self.bus = bus or MessageBus()
        self.events = EventLog()
        self.link = Link(
            config.connect,
            bus=self.bus,
            baud=config.baud,
            speed=config.speed,
            heartbeat_timeout=config.heartbeat_timeout,
        )
        self.vehicle = VehicleState(self.link)
        self.streams = StreamRequester(self.link, config.plan)
        self.vehicle.add_reboot_listener(self.streams.request_again)
        self.params = ParamClient(self.link, self.vehicle, self.events)
        self.outputs = [Output(address, self.link) for address in config.outputs]
        self.estimation = LiveEstimation(self.link) if config.estimate else None
        self.link.add_state_listener(lambda old, new: self.events.record("link", "link", old=old, new=new))
        if self.estimation is not None:  # the magnetometer's declination comes from the vehicle
            self.link.add_state_listener(
                lambda old, new: new == "connected" and self.params.request(DECLINATION_PARAMS)
            )
        replaying = self.link.address.kind == "tlog"  # a replayed log is not a new session
        self.recorder = SessionRecorder(self, config.record_dir) if config.record_dir and not replaying else None
        self._tasks: list[asyncio.Task] = []

    async def start(self) -> None:
        """Start every part as a task of the running loop (the recorder first, so it has the first byte)."""
        if self.recorder is not None:
            self.recorder.start()
        parts = [self.link.run(), self.vehicle.run(), self.params.run(), *(o.run() for o in self.outputs)]
        if self.config.request_streams:
            parts.append(self.streams.run())
        if self.estimation is not None:
            parts.append(self.estimation.run())
        if self.recorder is not None:
            parts.append(self.recorder.run())
        self._tasks = [asyncio.create_task(p) for p in parts]

    async def stop(self) -> None:
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks = []
        if self.recorder is not None:
            self.recorder.close()

    async def link_finished(self) -> None:
        """Returns when the link has ended by itself (a replayed log reached its end)."""
        await self._tasks[0]

    def status(self) -> dict:
        return {
            "link": self.link.status(),
            "vehicle": self.vehicle.as_dict(),
            "streams": self.streams.report(),
            "outputs": [o.status() for o in self.outputs],
            "estimation": self.estimation.pipeline.summary() if self.estimation else None,
            "recording": self.recorder.status() if self.recorder else {"state": "off"},
        }
