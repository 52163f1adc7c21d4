"""A 3DR / SiK telemetry radio pair between the simulated vehicle and the ground station: the
57600-baud link an APM 2.5 flies with, and what it does when asked for more than it carries.

Vehicle → ground, in two stages, as on the real thing:
- the autopilot's UART at `baud` (8N1: baud / 10 bytes/s) with a small transmit buffer; like
  ArduPilot (HAVE_PAYLOAD_SPACE), the vehicle skips a message that does not fit in it. Each
  vehicle has its own (by the sysid in the packet's header): vehicles sharing a radio network
  share its air time and buffer, never one autopilot's serial port;
- the radio's serial buffer (`buffer_bytes`), sent over the air at `capacity_bps` (gcs.mavlink.radio:
  baud / 10 × SiK's efficiency, a modelled figure);
  bytes arriving at a full buffer are lost. Whole packets go out, so a UDP datagram is one packet.
The ground radio injects RADIO_STATUS (sysid 51 '3', compid 68 'D', as SiK does) once a second:
rssi / remrssi / noise / remnoise on SiK's 0-255 scale, rxerrors, fixed, and txbuf, the percentage
of the buffer free; it falls as the queue fills. (On real radios each end reports its own buffer:
the vehicle's radio tells the autopilot, the ground radio tells the ground station about the
uplink; here the buffer that fills is the downlink's, and it is the one reported.)
Ground → vehicle passes unlimited (the station sends little).
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import Callable

import numpy as np

from gcs.mavlink.dialect import Encoder, mavlink
from gcs.mavlink.radio import SIK_EFFICIENCY, link_capacity

#: SiK's RADIO_STATUS source: sysid '3', compid 'D'.
RADIO_SYSID, RADIO_COMPID = 51, 68
#: SiK's serial receive buffer (bytes waiting for air time).
SIK_BUFFER_BYTES = 2048
#: The autopilot's UART transmit buffer (bytes).
UART_BUFFER_BYTES = 512
#: How often the drain runs (s).
TICK = 0.01


class SikRadio:
    """The radio pair; `attach(endpoint)` returns the endpoint the vehicle writes through."""

    def __init__(
        self,
        baud: int = 57600,
        efficiency: float = SIK_EFFICIENCY,
        buffer_bytes: int = SIK_BUFFER_BYTES,
        mavlink1: bool = True,
        seed: int = 0,
    ) -> None:
        self.baud, self.efficiency, self.buffer_bytes = baud, efficiency, buffer_bytes
        self.uart_bps = baud / 10.0
        self.capacity_bps = link_capacity(baud, efficiency)
        self._encoder = Encoder(RADIO_SYSID, RADIO_COMPID, mavlink1=mavlink1)
        self._rng = np.random.default_rng(seed)
        self._queue: deque[bytes] = deque()
        self.queued = 0  # bytes in the radio's buffer
        self._uarts: dict[int, Uart] = {}  # each vehicle's, by sysid
        self._credit = 0.0
        self._last: float | None = None
        self.skipped = 0  # packets the vehicle did not send (UART full)
        self.overflowed = 0  # packets lost at a full radio buffer
        self.sent_bytes = 0

    # --- vehicle side ----------------------------------------------------------------------------

    def uart(self, sysid: int) -> Uart:
        """Vehicle `sysid`'s serial port to the radio."""
        return self._uarts.setdefault(sysid, Uart(self.uart_bps))

    def _drain_uarts(self, now: float) -> None:
        for uart in self._uarts.values():
            uart.drain(now)

    def offer(self, packet: bytes) -> None:
        """The vehicle sends a packet: skipped when its UART is full, lost when the radio is."""
        uart = self.uart(_sysid(packet))
        if not uart.has_room(len(packet)):
            self.skipped += 1
            return
        uart.level += len(packet)
        if self.queued + len(packet) > self.buffer_bytes:
            self.overflowed += 1
            return
        self._queue.append(packet)
        self.queued += len(packet)

    @property
    def txbuf(self) -> int:
        """Percent of the radio's buffer free (RADIO_STATUS.txbuf)."""
        return int(100 * (self.buffer_bytes - self.queued) / self.buffer_bytes)

    # --- the air -------------------------------------------------------------------------------

    def drain(self, now: float) -> list[bytes]:
        """The whole packets the air has carried since the last call."""
        self._drain_uarts(now)
        if self._last is not None:
            self._credit = min(self._credit + (now - self._last) * self.capacity_bps, self.buffer_bytes)
        self._last = now
        out = []
        while self._queue and len(self._queue[0]) <= self._credit:
            packet = self._queue.popleft()
            self._credit -= len(packet)
            self.queued -= len(packet)
            self.sent_bytes += len(packet)
            out.append(packet)
        if not self._queue:
            self._credit = 0.0  # idle air time is not banked
        return out

    def status(self) -> bytes:
        """The ground radio's RADIO_STATUS now."""
        noise = lambda mean: int(np.clip(mean + 3 * self._rng.standard_normal(), 0, 255))  # noqa: E731
        msg = mavlink.MAVLink_radio_status_message(noise(190), noise(182), self.txbuf, noise(42), noise(45), 0, 0)
        return self._encoder.encode(msg)

    def attach(self, endpoint) -> RadioEndpoint:
        return RadioEndpoint(self, endpoint)


class RadioEndpoint:
    """The vehicle's endpoint seen through the radio: writes queue for air time; reads pass."""

    def __init__(self, radio: SikRadio, endpoint) -> None:
        self.radio, self.endpoint = radio, endpoint
        self._task: asyncio.Task[None] | None = None

    async def open(self, on_data: Callable[[bytes], None]) -> None:
        await self.endpoint.open(on_data)
        self._task = asyncio.create_task(self._air())

    def write(self, packet: bytes) -> None:
        self.radio._drain_uarts(asyncio.get_running_loop().time())
        self.radio.offer(packet)

    async def _air(self) -> None:
        loop = asyncio.get_running_loop()
        next_status = loop.time()
        while True:
            now = loop.time()
            for packet in self.radio.drain(now):
                self.endpoint.write(packet)
            if now >= next_status:
                next_status = now + 1.0
                self.endpoint.write(self.radio.status())
            await asyncio.sleep(TICK)

    def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
        self.endpoint.close()


def fit_radio(sim, baud: int = 57600, seed: int = 0, radio: SikRadio | None = None) -> SikRadio:
    """Put a radio between `sim` (a SimVehicle) and the station: a new one, or `radio` shared with
    other vehicles (a multipoint network: one air time, one buffer). Its logger then sends as
    ArduPilot does on a serial port without flow control: one LOG_DATA per send loop, only when
    the UART has room."""
    radio = radio or SikRadio(baud, mavlink1=sim.profile.mavlink1, seed=seed)
    sim.radio = radio
    sim.log_server.sends_per_loop = 1
    sim.log_server.has_room = radio.uart(sim.sysid).has_room
    return radio


class Uart:
    """One autopilot's serial transmit buffer, drained at the port's `bps`."""

    def __init__(self, bps: float) -> None:
        self.bps = bps
        self.level = 0.0  # bytes waiting
        self._last: float | None = None

    def drain(self, now: float) -> None:
        if self._last is not None:
            self.level = max(0.0, self.level - (now - self._last) * self.bps)
        self._last = now

    def has_room(self, size: int = 105) -> bool:
        """HAVE_PAYLOAD_SPACE for a packet of `size` bytes (a MAVLink 1 LOG_DATA by default)."""
        return self.level + size <= UART_BUFFER_BYTES


def _sysid(packet: bytes) -> int:
    """The sender's sysid from a MAVLink 1 (0xFE) or 2 (0xFD) header."""
    return packet[5] if packet[0] == 0xFD else packet[3]
