"""A timeline of an asyncio event loop, to lay a slow request against: every callback (asyncio
`Handle._run`) with its start, end and the loop thread's CPU, every wait in the selector (the
loop idle), every garbage-collector pass on the loop's thread.

Installed in the process that runs the loop (bench.status does, with `--trace`); asyncio's own
loop only (uvloop's callbacks are not Python Handles). All times are CLOCK_MONOTONIC, so a
request's send and answer timed in another process (bench.status_pages) fall on the same line.

`explain(sent, answered, port)` splits one request's time: before the loop read its bytes (the
loop busy in callbacks ahead of it, idle in the selector, or between the two: the loop's own
work, or its thread not running), then the time to the answer; and names the longest callbacks in
the window. A GC pass runs inside a callback and is counted in it too.
"""

from __future__ import annotations

import asyncio
import bisect
import gc
import selectors
import threading
import time
from typing import Any, NamedTuple


class Span(NamedTuple):
    """One span of the timeline. Kept as a plain tuple of floats and strings while tracing: the
    collector stops tracking an exact tuple of those at its first pass (never a NamedTuple's), so
    a long trace does not lengthen the collections it is there to see (it did: 8,000 Spans in
    each young generation, 5 ms passes)."""

    start: float
    end: float
    cpu: float  # the loop thread's CPU in the span, s (0 for a selector wait)
    kind: str  # "callback", "select", "gc"
    what: str  # the callback, the GC generation, or the selector's event count
    port: int  # a socket transport's peer port (0: none)


class LoopTrace:
    def __init__(self) -> None:
        self.raw: list[tuple[float, float, float, str, str, int]] = []
        self.recording = False
        self._sorted: list[Span] = []
        self._starts: list[float] = []
        self._thread = 0
        self._gc_start = (0.0, 0.0)

    def install(self, loop: asyncio.AbstractEventLoop) -> None:
        """Hook the loop (call from its thread, before the window to trace)."""
        self._thread = threading.get_ident()
        self._original_run = original = asyncio.events.Handle._run
        trace = self

        def timed_run(handle: asyncio.events.Handle) -> None:
            if not trace.recording:
                return original(handle)
            start, cpu = time.monotonic(), time.thread_time()
            what, port = describe(handle)  # before: a handle's callback is gone once cancelled
            try:
                original(handle)
            finally:
                trace.raw.append((start, time.monotonic(), time.thread_time() - cpu, "callback", what, port))

        asyncio.events.Handle._run = timed_run  # type: ignore[method-assign]
        selector: selectors.BaseSelector = loop._selector  # type: ignore[attr-defined]
        self._selector, self._original_select = selector, selector.select

        def timed_select(timeout: float | None = None) -> list:
            start = time.monotonic()
            events = trace._original_select(timeout)
            if trace.recording:
                trace.raw.append((start, time.monotonic(), 0.0, "select", str(len(events)), 0))
            return events

        selector.select = timed_select  # type: ignore[method-assign]
        gc.callbacks.append(self._on_gc)

    def uninstall(self) -> None:
        self.recording = False
        asyncio.events.Handle._run = self._original_run  # type: ignore[method-assign]
        self._selector.select = self._original_select  # type: ignore[method-assign]
        gc.callbacks.remove(self._on_gc)

    def _on_gc(self, phase: str, info: dict[str, int]) -> None:
        if threading.get_ident() != self._thread or not self.recording:
            return
        if phase == "start":
            self._gc_start = (time.monotonic(), time.thread_time())
        else:
            start, cpu = self._gc_start
            what = f"gc generation {info['generation']}"
            self.raw.append((start, time.monotonic(), time.thread_time() - cpu, "gc", what, 0))

    @property
    def spans(self) -> list[Span]:
        """The timeline in order of start (a GC pass ends, and is kept, inside the callback that
        triggered it)."""
        return [Span._make(r) for r in sorted(self.raw)]

    def _sort(self) -> list[Span]:
        self._sorted = self.spans
        self._starts = [s.start for s in self._sorted]
        return self._sorted

    def explain(self, sent: float, answered: float, port: int | None = None) -> dict[str, Any]:
        """Where one request's time went, sent → answered (CLOCK_MONOTONIC s), in ms. `port`: the
        client's port, to find when the loop read this request's bytes."""
        spans = self._sorted if len(self._sorted) == len(self.raw) else self._sort()
        first = max(0, bisect.bisect_left(self._starts, sent) - 1)
        inside = [s for s in spans[first:] if s.end > sent and s.start < answered]
        read_at = None
        for s in inside:
            if s.kind == "callback" and s.start >= sent and s.port == port:
                read_at = s.start
                break

        def split(a: float, b: float) -> dict[str, float]:
            parts = {"callbacks": 0.0, "callbacks_cpu": 0.0, "of_which_gc": 0.0, "select": 0.0}
            for s in inside:
                overlap = min(s.end, b) - max(s.start, a)
                if overlap <= 0:
                    continue
                parts[{"callback": "callbacks", "gc": "of_which_gc"}.get(s.kind, s.kind)] += overlap
                if s.kind == "callback" and s.end > s.start:
                    parts["callbacks_cpu"] += s.cpu * overlap / (s.end - s.start)
            parts["neither"] = (b - a) - parts["callbacks"] - parts["select"]
            return {k: round(1000 * v, 2) for k, v in parts.items()}

        longest = sorted((s for s in inside if s.kind != "select"), key=lambda s: s.start - s.end)[:4]
        return {
            "ms": round(1000 * (answered - sent), 2),
            "before_read": split(sent, read_at) if read_at is not None else None,
            "after_read": split(read_at, answered) if read_at is not None else split(sent, answered),
            "longest": [
                {
                    "ms": round(1000 * (s.end - s.start), 2),
                    "cpu_ms": round(1000 * s.cpu, 2),
                    "at_ms": round(1000 * (s.start - sent), 2),
                    "what": s.what,
                }
                for s in longest
            ],
        }


def describe(handle: Any) -> tuple[str, int]:
    """A callback's name (a task step: its coroutine's) and its socket transport's peer port."""
    callback = getattr(handle, "_callback", None)
    owner = getattr(callback, "__self__", None)
    if isinstance(owner, asyncio.Task):
        return f"task {owner.get_coro().__qualname__}", 0  # type: ignore[union-attr]
    name = getattr(callback, "__qualname__", None) or type(callback).__name__
    port = 0
    if owner is not None and hasattr(owner, "get_extra_info"):
        peer = owner.get_extra_info("peername")
        port = peer[1] if isinstance(peer, tuple) else 0
    return str(name), port
