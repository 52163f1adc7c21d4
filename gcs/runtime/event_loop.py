"""The event loop the station's commands run on: uvloop where it is installed (uvicorn[standard]
brings it on Linux and macOS), asyncio's own loop elsewhere.

Why: the station's loop wakes for every burst of datagrams and every WebSocket send; libuv's loop
and its socket transports take a fraction of the CPU of asyncio's pure-Python ones per wake-up
(docs/benchmarks.md, "`gcs serve` and `gcs demo` on uvloop"). Nothing in gcs depends on which loop runs."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Coroutine, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

T = TypeVar("T")


def loop_factory() -> Callable[[], asyncio.AbstractEventLoop] | None:
    """uvloop's loop constructor, or None (asyncio's default) where uvloop is not installed."""
    try:
        import uvloop  # noqa: PLC0415 (optional: not on Windows)
    except ImportError:
        return None
    return uvloop.new_event_loop


def run(main: Coroutine[Any, Any, T]) -> T:
    """asyncio.run(main) on the fastest loop available."""
    with asyncio.Runner(loop_factory=loop_factory()) as runner:
        return runner.run(main)


@contextmanager
def loops_made_fast() -> Iterator[None]:
    """Within: `asyncio.new_event_loop()` makes the loop `run` runs on (for a library that makes
    its own loop in its own thread, such as viser's server, which makes it before its constructor
    returns). asyncio's own function is put back after. Not through an event-loop policy: those
    are deprecated from Python 3.14 (and uvloop's with them) and go in 3.16."""
    factory = loop_factory()
    if factory is None:
        yield
        return
    before = asyncio.new_event_loop
    asyncio.new_event_loop = factory
    try:
        yield
    finally:
        asyncio.new_event_loop = before
