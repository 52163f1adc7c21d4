"""A transport kept open: opened, reopened whenever it closes, with exponential backoff, and why
it cannot open said once per failing run (the link's `open_error`, its events). What a vehicle's
link and a forwarding output (gcs.runtime.forward) both do with their transports."""

from __future__ import annotations

import asyncio
import os
from collections.abc import Callable

from gcs.transport.pipes import BatchCallback, DataCallback, Transport


async def keep_open(
    make: Callable[[], Transport],
    on_data: DataCallback,
    on_event: Callable[[str, str], None],
    on_open: Callable[[Transport | None], None],
    first_backoff: float = 0.5,
    max_backoff: float = 5.0,
    on_batch: BatchCallback | None = None,
    on_refused: Callable[[str | None], None] | None = None,
) -> None:
    """Open a transport and reopen it whenever it closes, with exponential backoff.
    Returns when a transport that cannot be reopened (a replayed file) has ended.
    `on_batch`: a wake-up's datagrams in one call (gcs.transport.pipes). `on_refused`: why it
    cannot open ("cannot open ADDRESS: Connection refused") at the first failure, None once open."""
    backoff = first_backoff
    failing = False
    while True:
        transport = make()
        try:
            await transport.open(on_data, on_batch)
        except OSError as exc:
            if not failing:
                why = f"cannot open {transport.address}: {open_error(exc)}"
                on_event("transport", f"{why}; retrying")
                if on_refused is not None:
                    on_refused(why)
            failing = True
            await asyncio.sleep(backoff)
            backoff = min(backoff * 2, max_backoff)
            continue
        failing = False
        backoff = first_backoff
        if on_refused is not None:
            on_refused(None)
        on_open(transport)
        on_event("transport", f"opened {transport.address}")
        try:
            await transport.wait_closed()
        finally:
            transport.close()
            on_open(None)
        why = f": {transport.close_reason}" if transport.close_reason else ""
        on_event("transport", f"closed {transport.address}{why}")
        if not transport.reconnectable:
            return
        await asyncio.sleep(backoff)


def open_error(exc: OSError) -> str:
    """Why a transport did not open, once: the reason an errno names ("No such file or directory",
    "Permission denied", "Connection refused"), else the error's own words. The whole error read
    "[Errno 2] cannot open serial port /dev/ttyUSB0: ..." after the line's own "cannot open ADDRESS"."""
    if isinstance(exc.errno, int) and exc.errno > 0:
        return os.strerror(exc.errno)
    return exc.strerror or str(exc)
