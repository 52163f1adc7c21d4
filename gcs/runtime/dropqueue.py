"""A bounded FIFO that never makes its producer wait: when it is full, the oldest item makes room
and is counted. The message bus gives one to each subscriber, the dashboard one to each viewer."""

from __future__ import annotations

import asyncio
from collections import deque
from typing import Generic, TypeVar

T = TypeVar("T")


class DropOldestQueue(Generic[T]):
    def __init__(self, maxlen: int) -> None:
        self.maxlen = maxlen
        self.items: deque[T] = deque()
        self.dropped = 0
        self._ready = asyncio.Event()

    def __len__(self) -> int:
        return len(self.items)

    def put(self, item: T) -> T | None:
        """Queue item now; returns the oldest item if it had to be dropped to make room."""
        lost = None
        if len(self.items) >= self.maxlen:
            lost = self.items.popleft()
            self.dropped += 1
        self.items.append(item)
        self._ready.set()
        return lost

    def put_many(self, items: list[T]) -> None:
        """`put` of each item in turn (the same items kept, the same count dropped), in one call."""
        if not items:
            return
        queued = self.items
        queued.extend(items)
        over = len(queued) - self.maxlen
        if over > 0:
            self.dropped += over
            for _ in range(over):
                queued.popleft()
        self._ready.set()

    async def wait(self, timeout: float | None = None) -> bool:
        """Until something is queued (True), or `timeout` s pass first (False).

        `asyncio.timeout`, not `wait_for`: on Python 3.11 `wait_for` can swallow a cancellation
        that arrives as the item does, and a stopping station would hang. Without a timeout none
        is set up: a viewer's sender waits here once per frame."""
        if timeout is None:
            while not self.items:
                self._ready.clear()
                await self._ready.wait()
            return True
        try:
            async with asyncio.timeout(timeout):
                while not self.items:
                    self._ready.clear()
                    await self._ready.wait()
        except TimeoutError:
            return False
        return True

    def get_nowait(self) -> T:
        return self.items.popleft()

    def drain(self, limit: int | None = None) -> list[T]:
        """Everything queued now (at most `limit` items), oldest first, without waiting."""
        if limit is not None and limit < len(self.items):
            return [self.items.popleft() for _ in range(limit)]
        items = list(self.items)
        self.items.clear()
        return items
