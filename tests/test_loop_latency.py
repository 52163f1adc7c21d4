"""What keeps the event loop answering quickly while it serves (docs/benchmarks.md, issue 17):
the start-up heap frozen out of the collector's walk while a station serves, and handed back
when it stops."""

from __future__ import annotations

import asyncio
import gc

from live import dashboard, wait_for

from gcs.runtime.station import Station, StationConfig


def test_start_up_heap_frozen_while_serving(udp_port):
    async def run() -> tuple[int, int, int, int]:
        gc.unfreeze()  # whatever an earlier test left
        station = Station(StationConfig(connect=f"udpin:127.0.0.1:{udp_port}", request_streams=False))
        await station.start()
        try:
            # the estimators' kernels load in a thread, then everything alive is frozen
            await wait_for(lambda: gc.get_freeze_count() > 0, 120, "the estimators warmed and froze the heap")
            with_station = gc.get_freeze_count()
            async with dashboard(station, viser=False):
                with_server = gc.get_freeze_count()
                walked = len(gc.get_objects())  # what a full collection walks now
            after_server = gc.get_freeze_count()
        finally:
            await station.stop()
        return with_station, with_server, walked, after_server + gc.get_freeze_count()

    with_station, with_server, walked, after_stop = asyncio.run(run())
    assert with_server > with_station > 0
    # a full pass walks a small part of the process: the start-up objects are frozen
    assert walked < with_server / 4, (walked, with_server)
    assert after_stop == 0  # handed back: a stopped station's cycles are collected again
