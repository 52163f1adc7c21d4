"""The session's event log in memory: every change a person or the link made (gain changes
with old and new value and which client, parameter writes, link state changes, notes).

Producers call `record`; consumers (the session recorder, the dashboard) connect to `recorded`.
The recent events are kept for the status page; the recorder keeps them all on disk.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from gcs.runtime.signal import Signal


@dataclass(frozen=True, slots=True)
class Event:
    wall_time: float  # UNIX time, s
    host_time: float  # monotonic, s
    kind: str  # "gain", "param", "link", "note", "recording", ...
    client: str  # who caused it: "cli", "api:127.0.0.1", "viser", "link", ...
    data: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {
            "wall_time": self.wall_time,
            "host_time": self.host_time,
            "kind": self.kind,
            "client": self.client,
            **self.data,
        }


class EventLog:
    def __init__(self, keep: int = 1000) -> None:
        self.recent: deque[Event] = deque(maxlen=keep)
        self.recorded: Signal[[Event]] = Signal()

    def record(self, kind: str, client: str, **data: Any) -> Event:
        event = Event(time.time(), time.monotonic(), kind, client, data)
        self.recent.append(event)
        self.recorded.emit(event)
        return event
