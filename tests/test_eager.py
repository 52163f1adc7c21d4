"""gcs.server.eager.start: a coroutine's first step runs in the caller's turn; one that waits is
finished by a task exactly as a task would have run it (its result, its exceptions, its
cancellation, a bare turn of the loop), on asyncio's loop and on the servers' uvloop."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Coroutine
from typing import Any

import pytest

from gcs.runtime import event_loop
from gcs.server import eager

Run = Callable[[Coroutine[Any, Any, Any]], Any]


@pytest.fixture(params=["asyncio", "station"])
def run_on(request: pytest.FixtureRequest) -> Run:
    """asyncio.run, or the station's own loop (uvloop where installed: what `gcs serve` runs on)."""
    return asyncio.run if request.param == "asyncio" else event_loop.run


def test_a_coroutine_that_does_not_wait_runs_to_its_end_before_start_returns(run_on: Run):
    done: list[str] = []

    async def work() -> None:
        done.append("written")

    async def run() -> tuple[asyncio.Task[None] | None, list[str]]:
        task = eager.start(work())
        return task, list(done)

    task, seen = run_on(run())
    assert task is None and seen == ["written"]


def test_its_exception_is_raised_by_start(run_on: Run):
    async def fail() -> None:
        raise ConnectionResetError("gone")

    async def run() -> None:
        eager.start(fail())

    with pytest.raises(ConnectionResetError):
        run_on(run())


def test_a_coroutine_that_waits_is_finished_by_a_task_with_what_it_waited_for(run_on: Run):
    steps: list[object] = []

    async def work(ready: asyncio.Event, value: asyncio.Future[int]) -> None:
        steps.append("first")
        await ready.wait()
        steps.append(await value)
        await asyncio.sleep(0)  # a bare turn of the loop (a None yield)
        steps.append("last")

    async def run() -> tuple[list[object], bool]:
        ready, value = asyncio.Event(), asyncio.get_running_loop().create_future()
        task = eager.start(work(ready, value))
        assert task is not None
        before = list(steps)
        ready.set()
        value.set_result(7)
        async with asyncio.timeout(30):
            await task
        return before, task.done()

    before, done = run_on(run())
    assert before == ["first"] and done and steps == ["first", 7, "last"]


def test_an_exception_after_waiting_ends_the_task_with_it(run_on: Run):
    async def work(value: asyncio.Future[int]) -> None:
        await value
        raise ConnectionResetError("gone while waiting")

    async def run() -> BaseException | None:
        value = asyncio.get_running_loop().create_future()
        task = eager.start(work(value))
        assert task is not None
        value.set_result(1)
        async with asyncio.timeout(30):
            await asyncio.wait([task])
        return task.exception()

    assert isinstance(run_on(run()), ConnectionResetError)


def test_cancelling_the_task_cancels_the_coroutine_where_it_waits(run_on: Run):
    seen: list[str] = []

    async def work(never: asyncio.Event) -> None:
        try:
            await never.wait()
        except asyncio.CancelledError:
            seen.append("cancelled in the wait")
            raise

    async def run() -> tuple[bool, int]:
        never = asyncio.Event()
        task = eager.start(work(never))
        assert task is not None
        await asyncio.sleep(0)
        task.cancel()
        async with asyncio.timeout(30):
            await asyncio.wait([task])
        return task.cancelled(), len(never._waiters)  # type: ignore[attr-defined]

    cancelled, waiters = run_on(run())
    assert cancelled and seen == ["cancelled in the wait"] and waiters == 0
