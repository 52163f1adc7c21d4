"""The serial end of the simulated vehicle: a pseudo-terminal whose slave appears at a chosen path.

A ground station opens that path as if it were a USB or radio serial port. Closing the endpoint
removes the symlink and closes the master, so the ground station's reads fail with EIO exactly
as when a USB cable is pulled; opening a new endpoint at the same path plugs it back in.

The vehicle keeps its own slave descriptor open for as long as the port exists: with no slave
open, Linux reports EIO on the master, which would look like a hang-up before anyone connected.
"""

from __future__ import annotations

import asyncio
import os
import tty

from gcs.transport.address import Address
from gcs.transport.pipes import BatchCallback, DataCallback, SerialTransport


class PtyTransport(SerialTransport):
    """Vehicle side of a pseudo-terminal serial port exposed as a symlink at `path`.

    Reads and writes the master exactly as SerialTransport reads and writes a device (event-loop
    reader, non-blocking writes that drop and count when the buffer is full); only opening and
    closing differ.
    """

    def __init__(self, path: str) -> None:
        super().__init__(Address("pty", path=path))
        self.path = path
        self._master: int | None = None
        self._slave: int | None = None

    async def open(self, on_data: DataCallback, on_batch: BatchCallback | None = None) -> None:
        if os.path.lexists(self.path) and not os.path.islink(self.path):
            raise OSError(f"{self.path} exists and is not a symlink; not replacing it")
        self._new_closed_future()
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line discipline: bytes pass through untouched
        os.set_blocking(master, False)
        if os.path.islink(self.path):
            os.unlink(self.path)  # left behind by a vehicle that was killed
        os.symlink(os.ttyname(slave), self.path)
        self._master, self._slave, self._fd, self._on_data = master, slave, master, on_data
        asyncio.get_running_loop().add_reader(master, self._readable)

    def close(self) -> None:
        super().close()  # stops reading, marks the transport closed
        if self._master is None or self._slave is None:  # both are set by open() or neither
            return
        try:
            if os.path.islink(self.path) and os.readlink(self.path) == os.ttyname(self._slave):
                os.unlink(self.path)
        except OSError:
            pass
        os.close(self._master)
        os.close(self._slave)
        self._master = self._slave = None
