"""uvicorn's server with its housekeeping tick once a second instead of ten times.

`uvicorn.Server.main_loop` wakes every 0.1 s to run `on_tick`, whose work is once a second (the
Date header) but for one check: whether to exit. A wake-up of an otherwise idle loop costs
0.1-0.2 ms of CPU (docs/benchmarks.md, "`gcs serve` when little arrives"): the ten a second were
~1 ms/s for nothing. Here the tick is once a second, and setting `should_exit` (our stop, or
uvicorn's own SIGINT/SIGTERM handler) wakes it at once, so a stop waits no longer than before."""

from __future__ import annotations

import asyncio
import contextlib

import uvicorn

#: s between two ticks; on_tick's counter advances by the ticks of 0.1 s it stands for
TICK = 1.0


class DashboardUvicorn(uvicorn.Server):
    def __init__(self, config: uvicorn.Config) -> None:
        self._exit = asyncio.Event()
        self._should_exit = False
        super().__init__(config)

    @property
    def should_exit(self) -> bool:
        return self._should_exit

    @should_exit.setter
    def should_exit(self, value: bool) -> None:
        self._should_exit = value
        if value:
            self._exit.set()

    async def main_loop(self) -> None:
        counter = 0
        while not await self.on_tick(counter):
            counter = (counter + round(TICK / 0.1)) % 864000  # a multiple of 10: on_tick's once-a-second work runs
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(TICK):
                    await self._exit.wait()
