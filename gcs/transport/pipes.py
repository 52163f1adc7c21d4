"""Byte pipes to a vehicle or a peer: UDP, TCP, serial and a replayed .tlog.

Every transport has the same small surface, so the link and the simulator never care which one:

    await t.open(on_data)   # start delivering received bytes to on_data; OSError if not now
    await t.open(on_data, on_batch)   # UDP: every datagram one wake-up read, in one on_batch call
    t.write(data)           # never blocks: what cannot be sent now is dropped and counted
    await t.wait_closed()   # returns when the pipe is gone (peer hung up, device vanished)
    t.close()

Received bytes are handed over in the event loop's own callback, without a queue: the link's work
per chunk is small and bounded, so nothing downstream can make the reader wait. A reader that
gives `on_batch` gets what one wake-up read in one call (a UDP socket's datagrams, up to
UDP_READ_BATCH; a stream's chunk is already one read), so its fixed costs are paid per wake-up.
"""

from __future__ import annotations

import asyncio
import errno
import math
import os
import socket
import struct
import sys
from abc import ABC, abstractmethod
from collections.abc import Callable

import serial  # pyserial

from gcs.mavlink.tlog import MAX_WAIT_S, read_tlog_records
from gcs.transport.address import Address, parse_address

DataCallback = Callable[[bytes], None]
#: The datagrams one wake-up read, in arrival order (never empty).
BatchCallback = Callable[[list[bytes]], None]

#: Seconds a `tcp:` dial waits for the server's answer: a host that drops SYNs (a firewall, a
#: board switched off behind a router that keeps its address) otherwise held the open for the
#: kernel's ~2 min of retries, with no word of why and no retry. A lost SYN is resent after 1 and
#: 3 s, so a slow but live path still answers within it.
TCP_CONNECT_TIMEOUT = 5.0
#: Bytes a TCP peer may leave unread before further writes to it are dropped.
TCP_WRITE_LIMIT = 1 << 20
#: UDP receive buffer asked of the kernel: at 400 Hz of telemetry the default ~208 KB fills in
#: a fraction of a second if the event loop is starved (a busy laptop), and packets are lost.
UDP_RECEIVE_BUFFER = 4 << 20
#: Datagrams read per wake-up at most: a flood is drained without holding the event loop for
#: long (~2-3 ms of the station's receive path), and faster than a busy loop's other work per
#: turn lets it arrive (gcs.runtime.estimation.BATCH).
UDP_READ_BATCH = 256

#: Seconds after its last datagram a `udpin` peer is still sent to (a restarted sender's old port
#: is forgotten after that).
UDP_PEER_TIMEOUT = 10.0
#: Senders a `udpin` socket keeps and answers at most, the most recently heard: a datagram from
#: each of 25 000 source ports (anyone who can reach the port; with forged source addresses,
#: millions) made each of the station's packets go to all of them, 25 000 sendto per heartbeat,
#: and a reflector towards every forged address. 64: a fleet on one port, with room to spare.
UDP_MAX_PEERS = 64
UDP_MAX_DATAGRAM = 65535
#: Linux's SO_RXQ_OVFL (socket(7); Python has no constant for it): the drop count per datagram.
SO_RXQ_OVFL = 40
_DROPS_CMSG_SPACE = socket.CMSG_SPACE(4)


class Transport(ABC):
    """One byte pipe. `reconnectable` says whether reopening after close makes sense."""

    reconnectable = True

    def __init__(self, address: Address) -> None:
        self.address = address
        self.dropped_writes = 0
        self.kernel_drops = 0  # received datagrams the kernel dropped before we read them (UDP on Linux)
        #: why it closed by itself, when it knows (a serial device that vanished); None otherwise
        self.close_reason: str | None = None
        #: told why when the other end went while the transport stays open (a `tcpin` listener's
        #: last client hung up); set by its user
        self.on_peer_gone: Callable[[str], None] | None = None
        self._closed: asyncio.Future[None] | None = None

    @abstractmethod
    async def open(self, on_data: DataCallback, on_batch: BatchCallback | None = None) -> None:
        """Deliver what is received to on_data, or a wake-up's datagrams to on_batch when given
        (a transport that reads one chunk per wake-up calls on_data)."""

    def pace_reads(self, interval: Callable[[], float]) -> bool:
        """Read at most once per interval() s while not behind, if this transport can (a UDP
        socket): True if it does."""
        return False

    @abstractmethod
    def write(self, data: bytes) -> None: ...

    @abstractmethod
    def close(self) -> None: ...

    async def wait_closed(self) -> None:
        assert self._closed is not None, "open() first"
        await asyncio.shield(self._closed)

    def _new_closed_future(self) -> None:
        self._closed = asyncio.get_running_loop().create_future()

    def _mark_closed(self) -> None:
        if self._closed is not None and not self._closed.done():
            self._closed.set_result(None)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.address})"


class UdpTransport(Transport):
    """`udpin` binds and answers every peer heard in the last UDP_PEER_TIMEOUT s, UDP_MAX_PEERS at
    most (several vehicles or simulators sending to one port each get what the station sends, and
    each picks what is addressed to it, as on a radio); `udpout` sends to a fixed peer.

    A UDP pipe never "closes" when the peer goes away: the link notices silence by the
    missing heartbeats and resumes as soon as packets return.

    The socket is read with recvmsg from the loop's reader callback (asyncio's datagram
    transport hides ancillary data), up to UDP_READ_BATCH datagrams per wake-up. Paced
    (`pace_reads`), a wake-up that read fewer than that stops watching the socket for the interval,
    then reads what came meanwhile at once, and goes on reading once per interval on that timer
    while datagrams keep coming (`_poll`): a vehicle sending each message in its own datagram
    would otherwise wake the loop up to a thousand times a second, where the estimation and the
    dashboard take what arrived once per frame anyway. A read that follows two intervals without
    any starts no hold: datagrams that come that seldom are read as they come, and the hold's
    timer would be a second wake-up for each of them (~0.1 ms of CPU each, docs/benchmarks.md,
    "`gcs serve` when little arrives"). On Linux
    SO_RXQ_OVFL makes every datagram carry the socket's cumulative count of datagrams the
    kernel dropped for want of receive buffer: `kernel_drops`, the loss a flood or a starved
    loop causes before any sequence number can show it.
    """

    def __init__(self, address: Address) -> None:
        super().__init__(address)
        self.peer: tuple | None = None  # the last sender (udpin) or the fixed peer (udpout)
        #: udpin: the senders (at most UDP_MAX_PEERS), with when each was last heard (loop time)
        self.peers: dict[tuple, float] = {}
        self._sock: socket.socket | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._on_data: DataCallback | None = None
        self._on_batch: BatchCallback | None = None
        self._read_interval: Callable[[], float] | None = None
        self._resume: asyncio.TimerHandle | None = None
        self._watched = False  # the loop's reader is on the socket
        self._last_read = -math.inf  # loop time of the last read that brought datagrams

    async def open(self, on_data: DataCallback, on_batch: BatchCallback | None = None) -> None:
        loop = asyncio.get_running_loop()
        host, port = self.address.host, self.address.port
        family = socket.AF_INET6 if ":" in host else socket.AF_INET  # "localhost" is 127.0.0.1, as before
        family, _, _, _, sockaddr = (await loop.getaddrinfo(host, port, family=family, type=socket.SOCK_DGRAM))[0]
        sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            sock.setblocking(False)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, UDP_RECEIVE_BUFFER)  # capped by rmem_max
            if sys.platform == "linux":
                sock.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
            if self.address.kind == "udpin":
                sock.bind(sockaddr)
            else:
                self.peer = sockaddr
        except OSError:
            sock.close()
            raise
        self._sock, self._loop, self._on_data, self._on_batch = sock, loop, on_data, on_batch
        self._new_closed_future()
        loop.add_reader(sock.fileno(), self._readable)
        self._watched = True

    @property
    def local_port(self) -> int:
        assert self._sock is not None
        port: int = self._sock.getsockname()[1]
        return port

    def pace_reads(self, interval: Callable[[], float]) -> bool:
        self._read_interval = interval
        return True

    def _readable(self) -> None:
        """Read up to UDP_READ_BATCH datagrams, then hand them over: to on_batch in one call, else
        one by one to on_data."""
        datagrams = self._read()
        if not datagrams:
            return
        if self._read_interval is not None and len(datagrams) < UDP_READ_BATCH and self._loop is not None:
            interval, now = self._read_interval(), self._loop.time()
            if now - self._last_read < 2 * interval:  # they come faster than that: hold
                self._hold(interval)
            self._last_read = now
        if self._on_batch is not None:
            self._on_batch(datagrams)
            return
        on_data = self._on_data
        assert on_data is not None  # set by open() before the reader exists
        for data in datagrams:
            on_data(data)

    def _hold(self, seconds: float) -> None:
        """Leave the socket unwatched for `seconds`, then read it (`_poll`); what arrives meanwhile
        waits in its buffer."""
        if self._sock is None or self._loop is None:
            return
        if self._watched:
            self._loop.remove_reader(self._sock.fileno())
            self._watched = False
        self._resume = self._loop.call_later(seconds, self._poll)

    def _poll(self) -> None:
        """Read what came during a hold. While datagrams keep coming, each read holds again and
        the socket stays unwatched: a steady stream is read on this timer alone, without the
        watch's two epoll_ctl calls per interval. A read that finds nothing (the stream paused)
        or a whole batch (a flood: more is waiting) watches the socket again."""
        self._resume = None
        if self._sock is None or self._loop is None:
            return
        self._readable()
        if self._resume is None and self._sock is not None:  # not held again
            self._loop.add_reader(self._sock.fileno(), self._readable)
            self._watched = True

    def _read(self) -> list[bytes]:
        """The datagrams waiting, up to UDP_READ_BATCH. The drop count is cumulative, so only the
        last datagram's is read, and every peer heard in one wake-up is stamped with its time."""
        udpin = self.address.kind == "udpin"
        datagrams: list[bytes] = []
        ancdata: list = []
        heard = None
        try:
            for _ in range(UDP_READ_BATCH):
                sock = self._sock
                if sock is None:
                    break
                try:
                    data, anc, _flags, addr = sock.recvmsg(UDP_MAX_DATAGRAM, _DROPS_CMSG_SPACE)
                except (BlockingIOError, InterruptedError):
                    break
                except ConnectionRefusedError:
                    continue  # ICMP "port unreachable" while the peer is not listening yet
                except OSError as exc:
                    self.close_reason = f"socket error ({describe_error(exc)})"
                    self.close()
                    break
                ancdata = anc
                if udpin:
                    if addr != self.peer:
                        self.peer = addr
                        heard = None
                    if heard is None:
                        heard = self._loop.time() if self._loop is not None else 0.0
                        self._heard(addr, heard)
                datagrams.append(data)
        finally:
            for level, kind, payload in ancdata:
                if level == socket.SOL_SOCKET and kind == SO_RXQ_OVFL and len(payload) >= 4:
                    self.kernel_drops = struct.unpack("=I", payload[:4])[0]
        return datagrams

    def _heard(self, addr: tuple, when: float) -> None:
        """`addr` is the newest peer; past UDP_MAX_PEERS the one heard least lately is forgotten
        (`peers` is kept in the order last heard)."""
        peers = self.peers
        peers.pop(addr, None)
        if len(peers) >= UDP_MAX_PEERS:
            del peers[next(iter(peers))]
        peers[addr] = when

    def write(self, data: bytes) -> None:
        if self._sock is None or self.peer is None:
            self.dropped_writes += 1
            return
        for peer in self._recent_peers():
            try:
                self._sock.sendto(data, peer)
            except OSError:  # full send buffer, unreachable peer: dropped, never waited for
                self.dropped_writes += 1

    def _recent_peers(self) -> list[tuple]:
        """udpin: the peers heard lately (the last sender always); udpout: the peer."""
        assert self.peer is not None
        if len(self.peers) < 2 or self._loop is None:
            return [self.peer]
        since = self._loop.time() - UDP_PEER_TIMEOUT
        for gone in [p for p, heard in self.peers.items() if heard < since and p != self.peer]:
            del self.peers[gone]
        return list(self.peers)

    def close(self) -> None:
        if self._resume is not None:
            self._resume.cancel()
            self._resume = None
        if self._sock is not None:
            if self._loop is not None and not self._loop.is_closed():
                self._loop.remove_reader(self._sock.fileno())
            self._sock.close()
            self._sock = None
        self._mark_closed()


class _StreamProtocol(asyncio.Protocol):
    def __init__(self, on_data: DataCallback, on_lost: Callable[[_StreamProtocol], None]) -> None:
        self.on_data = on_data
        self.on_lost = on_lost
        self.transport: asyncio.Transport | None = None
        #: why the connection ended: None (the other end closed it, or we did) or the socket's error
        self.lost_error: Exception | None = None

    def connection_made(self, transport) -> None:
        self.transport = transport
        sock = transport.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def data_received(self, data: bytes) -> None:
        self.on_data(data)

    def connection_lost(self, exc: Exception | None) -> None:
        self.lost_error = exc
        self.on_lost(self)

    def write(self, data: bytes) -> bool:
        t = self.transport
        if t is None or t.is_closing() or t.get_write_buffer_size() > TCP_WRITE_LIMIT:
            return False
        t.write(data)
        return True


class TcpClientTransport(Transport):
    """`tcp:HOST:PORT`: dial a server. Closes when the peer hangs up (`close_reason` says whether
    it closed the connection or the socket failed); the link redials."""

    def __init__(self, address: Address) -> None:
        super().__init__(address)
        self._protocol: _StreamProtocol | None = None

    async def open(self, on_data: DataCallback, on_batch: BatchCallback | None = None) -> None:
        loop = asyncio.get_running_loop()
        self._new_closed_future()
        try:
            async with asyncio.timeout(TCP_CONNECT_TIMEOUT):
                _, self._protocol = await loop.create_connection(
                    lambda: _StreamProtocol(on_data, self._lost), self.address.host, self.address.port
                )
        except TimeoutError as exc:  # the OSError the link's retry names: "cannot open ...: <this>"
            if exc.errno is not None:  # the kernel's own timeout, first
                raise
            raise OSError(f"no answer within {TCP_CONNECT_TIMEOUT:g} s (connection timed out)") from None

    def _lost(self, protocol: _StreamProtocol) -> None:
        if self._closed is not None and not self._closed.done():  # not closed by us
            error = protocol.lost_error
            if error is None:
                self.close_reason = "the remote end closed the connection"
            elif isinstance(error, BrokenPipeError | ConnectionResetError):  # found by a write: closed all the same
                self.close_reason = f"the remote end closed the connection ({describe_error(error)})"
            else:
                words = describe_error(error) if isinstance(error, OSError) else str(error)
                self.close_reason = f"connection error ({words})"
        self._mark_closed()

    def write(self, data: bytes) -> None:
        if self._protocol is None or not self._protocol.write(data):
            self.dropped_writes += 1

    def close(self) -> None:
        if self._protocol is not None and self._protocol.transport is not None:
            self._protocol.transport.close()
        self._mark_closed()


class TcpServerTransport(Transport):
    """`tcpin:HOST:PORT`: listen; every connected client receives what is written and may send.

    The listener stays open while clients come and go, so it only closes when told to; its last
    client hanging up is told to `on_peer_gone`.
    """

    def __init__(self, address: Address) -> None:
        super().__init__(address)
        self._server: asyncio.base_events.Server | None = None
        self.clients: list[_StreamProtocol] = []

    async def open(self, on_data: DataCallback, on_batch: BatchCallback | None = None) -> None:
        loop = asyncio.get_running_loop()
        self._new_closed_future()

        def new_client() -> _StreamProtocol:
            p = _StreamProtocol(on_data, self._client_lost)
            self.clients.append(p)
            return p

        self._server = await loop.create_server(new_client, self.address.host, self.address.port, reuse_address=True)

    def _client_lost(self, client: _StreamProtocol) -> None:
        self.clients.remove(client)
        listening = self._closed is not None and not self._closed.done()  # (not our own close)
        if not self.clients and listening and self.on_peer_gone is not None:
            self.on_peer_gone("the last client closed the connection")

    @property
    def local_port(self) -> int:
        assert self._server is not None
        return self._server.sockets[0].getsockname()[1]

    def write(self, data: bytes) -> None:
        if not self.clients:
            self.dropped_writes += 1
        for client in self.clients:
            if not client.write(data):
                self.dropped_writes += 1

    def close(self) -> None:
        for client in list(self.clients):
            if client.transport is not None:
                client.transport.close()
        if self._server is not None:
            self._server.close()
        self._mark_closed()


def describe_error(exc: OSError) -> str:
    """The words of an OSError's errno ("Input/output error", "Connection reset by peer"), else
    its own text."""
    return os.strerror(exc.errno) if exc.errno else str(exc)


def open_serial(path: str, baud: int) -> serial.Serial:
    """The serial port at path, non-blocking; OSError with one line (`cannot open serial port
    PATH: No such file or directory`), not pyserial's message nested in another."""
    try:
        return serial.Serial(path, baud, timeout=0, exclusive=False)
    except serial.SerialException as exc:
        reason = os.strerror(exc.errno) if isinstance(exc.errno, int) else str(exc)
        raise OSError(exc.errno or errno.ENODEV, f"cannot open serial port {path}: {reason}") from None


def probe_serial(path: str, baud: int) -> None:
    """Open and close the port: a command fails at once, in one line, on a port that is not
    there, rather than waiting for it as a running link does (OSError as open_serial)."""
    open_serial(path, baud).close()


class SerialTransport(Transport):
    """A serial device (USB CDC, FTDI + telemetry radio, a pseudo-terminal).

    Read through the event loop's reader callback on the non-blocking descriptor. A device
    that vanishes (unplugged USB, closed pty master) shows up as EIO or end-of-file: the
    transport closes and the link reopens the same path when it is back.
    """

    def __init__(self, address: Address, baud: int = 57600) -> None:
        super().__init__(address)
        self.baud = baud
        self._port: serial.Serial | None = None
        self._fd: int | None = None

    async def open(self, on_data: DataCallback, on_batch: BatchCallback | None = None) -> None:
        self._new_closed_future()
        self._port = open_serial(self.address.path, self.baud)
        self._fd = self._port.fileno()
        os.set_blocking(self._fd, False)
        self._on_data = on_data
        asyncio.get_running_loop().add_reader(self._fd, self._readable)

    def _readable(self) -> None:
        assert self._fd is not None  # the event loop calls this only between open() and close()
        try:
            data = os.read(self._fd, 4096)
        except BlockingIOError:
            return
        except OSError as exc:
            self.close_reason = f"the device is gone ({describe_error(exc)})"
            self.close()
            return
        if not data:
            self.close_reason = "the device is gone (end of file)"
            self.close()
            return
        self._on_data(data)

    def write(self, data: bytes) -> None:
        if self._fd is None:
            self.dropped_writes += 1
            return
        try:
            os.write(self._fd, data)
        except (BlockingIOError, OSError):
            self.dropped_writes += 1

    def close(self) -> None:
        if self._fd is not None:
            try:
                asyncio.get_running_loop().remove_reader(self._fd)
            except RuntimeError:
                pass
            self._fd = None
        if self._port is not None:
            try:
                self._port.close()
            except OSError:
                pass
            self._port = None
        self._mark_closed()


TLOG_TIMESTAMP = struct.Struct(">Q")


class TlogTransport(Transport):
    """A .tlog (8-byte big-endian µs timestamp + one MAVLink packet, repeated) played back
    as if it were a live link, at its recorded pace divided by `speed` (0 = as fast as possible).

    What is written to it is discarded. It closes at the end of the file and does not reopen.
    """

    reconnectable = False

    def __init__(self, address: Address, speed: float = 1.0) -> None:
        super().__init__(address)
        self.speed = speed
        self._task: asyncio.Task | None = None

    async def open(self, on_data: DataCallback, on_batch: BatchCallback | None = None) -> None:
        self._new_closed_future()
        self._records = read_tlog_records(self.address.path)  # OSError if the file is missing
        self._task = asyncio.get_running_loop().create_task(self._play(on_data))

    async def _play(self, on_data: DataCallback) -> None:
        loop = asyncio.get_running_loop()
        start_wall = loop.time()
        first_us = None
        try:
            for i, (usec, packet) in enumerate(self._records):
                if first_us is None:
                    first_us = usec
                if self.speed > 0:
                    due = start_wall + (usec - first_us) / 1e6 / self.speed
                    delay = due - loop.time()
                    if abs(delay) > MAX_WAIT_S:  # a gap or a damaged stamp: sent now, paced on from it
                        start_wall, first_us, delay = loop.time(), usec, 0.0
                    if delay > 0.001:
                        await asyncio.sleep(delay)
                elif i % 256 == 0:
                    await asyncio.sleep(0)
                on_data(packet)
        finally:
            self._mark_closed()

    def write(self, data: bytes) -> None:
        self.dropped_writes += 1

    def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
        self._mark_closed()


def make_transport(address: Address | str, baud: int = 57600, speed: float = 1.0) -> Transport:
    """The transport for a connection string or parsed Address."""
    if isinstance(address, str):
        address = parse_address(address)
    if address.kind in ("udpin", "udpout"):
        return UdpTransport(address)
    if address.kind == "tcp":
        return TcpClientTransport(address)
    if address.kind == "tcpin":
        return TcpServerTransport(address)
    if address.kind in ("serial", "pty"):
        return SerialTransport(Address("serial", path=address.path), baud)
    if address.kind == "tlog":
        return TlogTransport(address, speed)
    raise ValueError(f"no transport for {address}")
