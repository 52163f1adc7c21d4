"""Run a coroutine's first step in the caller's turn of the loop, and a task only if it waits:
Python 3.12's eager tasks, for the 3.11 the station runs on.

Why: a `/ws/live` send that can go out at once (the client's socket accepts it) does all its
work without waiting, but a task per send, or a task per client woken per frame, cost the loop
as much again in scheduling as the send itself (docs/benchmarks.md, "the fan-out's sends"). A
send that has to wait (the client is slow and its transport paused) is finished by a task, so
the caller never waits for it.
"""

from __future__ import annotations

import asyncio
from collections.abc import Coroutine
from typing import Any


def start(coro: Coroutine[Any, Any, None]) -> asyncio.Task[None] | None:
    """Run `coro` until it first waits. None if it finished (its exception, if any, raised
    here), else the task that finishes it."""
    try:
        waiting = coro.send(None)
    except StopIteration:
        return None
    return asyncio.ensure_future(_finish(coro, waiting))


async def _finish(coro: Coroutine[Any, Any, None], waiting: Any) -> None:
    """Go on where `start` left off, as a task would: wait for what `coro` yielded (a future, or
    None for one turn of the loop), then resume it with the outcome, the task's own
    cancellation included."""
    while True:
        failure: BaseException | None = None
        if waiting is not None:  # taken over as a task takes it: the future is awaited again here
            waiting._asyncio_future_blocking = False
        try:
            await (asyncio.sleep(0) if waiting is None else waiting)
        except BaseException as exc:  # every outcome goes back into coro, as a task's does
            failure = exc
        try:
            waiting = coro.send(None) if failure is None else coro.throw(failure)
        except StopIteration:
            return
