"""The live process's start-up objects, kept out of the garbage collector's way.

A full collection walks every tracked object. After start-up a station's process holds about
240,000 (modules, FastAPI's app, viser, numba's types and compiled kernels), and one full pass
took 150 ms on the event loop, 30–490 ms under load, at moments the collector picks
(bench.loop_stalls; docs/benchmarks.md). `freeze` moves everything alive into the permanent
generation (`gc.freeze`), which no collection walks: a full pass then costs what was allocated
since (about 1,500 objects live, under 1 ms). It does not collect first (a pass of its own on the
loop); what start-up garbage it freezes comes back with `release`, which a stopping server or
station calls so that a process that starts many of them (the tests) still collects their cycles.
"""

from __future__ import annotations

import gc


def freeze() -> None:
    """Exempt every object alive now from collection (after start-up work: imports, compiling)."""
    gc.freeze()


def release() -> None:
    """Give the frozen objects back to the collector."""
    gc.unfreeze()
