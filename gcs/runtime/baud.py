"""`baud="auto"` on a serial link: the usual baud rates tried in turn until one yields a valid
packet (MAVLink, or a text line for an ascii: address), before the link opens its port for good."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

from gcs.mavlink.ascii import AsciiAttitudeDecoder
from gcs.mavlink.framing import MavlinkDecoder
from gcs.transport.address import Address
from gcs.transport.pipes import make_transport

#: Baud rates tried by `baud="auto"`, most likely first (telemetry radio, then USB/companion).
AUTO_BAUDS = (57600, 115200, 921600, 500000, 230400, 38400, 19200, 9600)


async def detect_baud(
    address: Address,
    new_decoder: Callable[[], MavlinkDecoder | AsciiAttitudeDecoder],
    on_event: Callable[[str, str], None],
    listen: float = 1.5,
) -> int:
    """The first of AUTO_BAUDS at which `address` yields a packet within `listen` s, tried again
    every second until one does; a port that cannot open is told to `on_event` (kind, detail)."""
    while True:
        for baud in AUTO_BAUDS:
            decoder = new_decoder()
            transport = make_transport(address, baud=baud)

            def deliver(data: bytes, decoder: MavlinkDecoder | AsciiAttitudeDecoder = decoder) -> None:
                decoder.frames(data)

            try:
                await transport.open(deliver)
            except OSError as exc:
                on_event("transport", f"baud detection: cannot open {address}: {exc}")
                break
            try:
                deadline = time.monotonic() + listen
                while time.monotonic() < deadline and decoder.counters.packets == 0:
                    await asyncio.sleep(0.05)
            finally:
                transport.close()
            if decoder.counters.packets:
                return baud
        await asyncio.sleep(1.0)
