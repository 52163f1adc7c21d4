"""The serial end of the simulated vehicle: a pseudo-terminal whose slave appears at a chosen path.

A ground station opens that path as if it were a USB or radio serial port. Closing the endpoint
removes the symlink and closes the master, so the ground station's reads fail with EIO exactly
as when a USB cable is pulled; opening a new endpoint at the same path plugs it back in. A link
left by a vehicle killed with SIGKILL (its target gone) is replaced; a live one never is.

The vehicle keeps its own slave descriptor open for as long as the port exists: with no slave
open, Linux reports EIO on the master, which would look like a hang-up before anyone connected.
"""

from __future__ import annotations

import asyncio
import os
import tty

from gcs.transport.address import Address
from gcs.transport.pipes import BatchCallback, DataCallback, SerialTransport


def remove_stale_link(path: str) -> None:
    """Clear `path` for a new port: remove a symlink whose target is gone (left by a vehicle killed
    with SIGKILL, which could not remove it; its pseudo-terminal went with it). Anything else
    there is refused: a file or folder, and a link to a device that exists, which is another
    running vehicle's port (or a terminal that took its number since)."""
    if not os.path.lexists(path):
        return
    if not os.path.islink(path):
        raise OSError(f"{path} exists and is not a symlink; not replacing it")
    if os.path.exists(path):
        raise OSError(f"{path} links to {os.readlink(path)}, which is open (another vehicle's port?); not replacing it")
    os.unlink(path)


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
        remove_stale_link(self.path)
        self._new_closed_future()
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line discipline: bytes pass through untouched
        os.set_blocking(master, False)
        try:
            os.symlink(os.ttyname(slave), self.path)
        except FileExistsError:  # another vehicle made it since: it is theirs
            os.close(master)
            os.close(slave)
            raise OSError(f"{self.path} was just made by another program; not replacing it") from None
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
