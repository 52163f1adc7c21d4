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


class Client(str):
    """Who asked for a change: its name as the event log shows it ("api:127.0.0.1", "viser", "cli"),
    with what a request also tells of its sender (the browser's user agent, which token it carried)
    so that the audit names the client of every change and every refusal. A `str`, so it passes
    through every command that takes a client name."""

    user_agent: str | None
    token_id: str | None

    def __new__(cls, name: str, *, user_agent: str | None = None, token_id: str | None = None) -> Client:
        client = super().__new__(cls, name)
        client.user_agent, client.token_id = user_agent, token_id
        return client

    def details(self) -> dict[str, str]:
        return {k: v for k, v in (("user_agent", self.user_agent), ("token_id", self.token_id)) if v is not None}


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
        if isinstance(client, Client):
            data = {**data, **client.details()}
        event = Event(time.time(), time.monotonic(), kind, str(client), data)
        self.recent.append(event)
        self.recorded.emit(event)
        return event
