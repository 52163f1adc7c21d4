"""Station parts under supervision: each runs as its own task; one that raises is logged,
recorded in the event log and shown in the station's snapshot, and the others keep running."""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Coroutine
from dataclasses import dataclass
from typing import Any

from gcs.runtime.events import EventLog
from gcs.runtime.signal import Signal

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class PartStatus:
    name: str
    state: str  # "running", "failed", "finished"
    error: str | None = None  # "ExceptionType: message" of a failed part
    since: float = 0.0  # UNIX time of the last state change


class Supervisor:
    def __init__(self, events: EventLog) -> None:
        self.events = events
        self.changed: Signal[[PartStatus]] = Signal()
        self._tasks: dict[str, asyncio.Task[None]] = {}
        self._status: dict[str, PartStatus] = {}

    def start(self, name: str, coroutine: Coroutine[Any, Any, None]) -> asyncio.Task[None]:
        """Run one part as a task of the running loop."""
        task = asyncio.create_task(coroutine, name=f"gcs:{name}")
        self._tasks[name] = task
        self._status[name] = PartStatus(name, "running", since=time.time())
        task.add_done_callback(lambda t: self._done(name, t))
        return task

    def _done(self, name: str, task: asyncio.Task[None]) -> None:
        if task.cancelled():
            return  # stopped on purpose
        exc = task.exception()
        if exc is None:
            status = PartStatus(name, "finished", since=time.time())
        else:
            error = f"{type(exc).__name__}: {exc}"
            log.error("station part %s failed: %s", name, error, exc_info=exc)
            self.events.record("part", "station", part=name, event="failed", error=error)
            status = PartStatus(name, "failed", error, time.time())
        self._status[name] = status
        self.changed.emit(status)

    def statuses(self) -> list[PartStatus]:
        return list(self._status.values())

    def task(self, name: str) -> asyncio.Task[None]:
        return self._tasks[name]

    async def stop(self, first: str | None = None) -> None:
        """Cancel every part (`first` alone before the others) and wait for them to end."""
        if first in self._tasks:
            task = self._tasks.pop(first)
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
        tasks = list(self._tasks.values())
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        self._tasks.clear()
