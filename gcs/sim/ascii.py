"""The simulated vehicle running seed 000's firmware: no MAVLink, only `pitch,yaw,roll\\r\\n` lines.

The thesis firmware prints its own DCM estimate once per loop, about 10 lines a second
(seed-000 §10.1); here the simulated autopilot's estimate (what its ATTITUDE would report) is
printed in the chosen format at `rate_hz` of vehicle time. A fraction `malformed` of the lines
is damaged the way a radio link damages them (cut short, a byte turned to garbage), seeded, so a
ground station's count of bad lines can be checked.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import numpy as np

from gcs.mavlink.ascii import SEED000, AsciiFormat
from gcs.sim.vehicle import SimVehicle, open_endpoint


class AsciiFirmware:
    """Lines of `vehicle`'s onboard attitude; `advance(t)` returns the bytes due up to vehicle time t."""

    def __init__(
        self, vehicle: SimVehicle, fmt: AsciiFormat = SEED000, rate_hz: float = 10.0, malformed: float = 0.0
    ) -> None:
        if not 0.0 <= malformed <= 1.0:
            raise ValueError(f"malformed fraction {malformed} must be between 0 and 1")
        self.vehicle, self.format, self.period, self.malformed = vehicle, fmt, 1.0 / rate_hz, malformed
        self.rng = np.random.default_rng(vehicle.seed + 1000)
        self.lines = 0
        self.damaged = 0
        #: lines (and damaged ones among them) a full port buffer refused: a stalled reader
        self.lost = 0
        self.lost_damaged = 0
        self._next = 0.0
        self._chunk = (0, 0)  # lines and damaged lines in the last advance()

    def advance(self, t: float) -> bytes:
        out = bytearray()
        lines, damaged = self.lines, self.damaged
        while self._next <= t:
            self.vehicle.advance(self._next)  # the autopilot's loop runs up to the line's time
            line = self.format.line(*self.vehicle.autopilot.primary.euler()).encode()
            self.lines += 1
            if self.rng.random() < self.malformed:
                line = self._damage(line)
                self.damaged += 1
            out += line
            self._next += self.period
        self.vehicle.advance(t)
        self._chunk = (self.lines - lines, self.damaged - damaged)
        return bytes(out)

    def _damage(self, line: bytes) -> bytes:
        """One unreadable line for one good one: cut short before its last field, or a byte
        turned to garbage."""
        if self.rng.integers(2) == 0:
            last = line.rindex(self.format.separator.encode())
            return line[: int(self.rng.integers(1, last + 1))] + b"\r\n"
        k = int(self.rng.integers(len(line) - 2))
        return line[:k] + b"#" + line[k + 1 :]

    async def run(self, address: str, on_open: Callable[[], None] | None = None) -> None:
        """Serve the lines on a pty:, udpout:, udpin:, tcp: or tcpin: address until cancelled."""
        endpoint = open_endpoint(address)
        await endpoint.open(lambda data: None)  # the firmware ignores what it is sent
        if on_open is not None:
            on_open()
        loop = asyncio.get_running_loop()
        speed = self.vehicle.speed
        wall0, vehicle0 = loop.time(), self.vehicle.t
        try:
            while True:
                data = self.advance(vehicle0 + (loop.time() - wall0) * speed)
                if data:
                    refused = endpoint.dropped_writes
                    endpoint.write(data)
                    if endpoint.dropped_writes > refused:
                        self.lost += self._chunk[0]
                        self.lost_damaged += self._chunk[1]
                await asyncio.sleep(self.period / speed)
        finally:
            endpoint.close()
