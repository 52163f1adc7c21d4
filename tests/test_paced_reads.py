"""Paced reads: a UDP link read at most once per interval (the dashboard's frame interval), so a
vehicle sending each message in its own datagram wakes the station's loop once per frame, not
once per message; a read that fills a whole batch (a flood) is not held. Real sockets on loopback."""

from __future__ import annotations

import asyncio
import socket

from live import wait_for

from gcs.mavlink.dialect import Encoder, mavlink
from gcs.runtime.estimation import LiveEstimation
from gcs.runtime.link import Link
from gcs.transport.address import Address
from gcs.transport.pipes import UDP_READ_BATCH, UdpTransport


class Batches:
    """What a transport hands over, call by call, with the loop time of each call."""

    def __init__(self) -> None:
        self.calls: list[tuple[float, list[bytes]]] = []
        self.changed = asyncio.Event()

    def __call__(self, datagrams: list[bytes]) -> None:
        self.calls.append((asyncio.get_running_loop().time(), list(datagrams)))
        self.changed.set()

    async def until(self, count: int, timeout: float) -> None:
        """Until `count` datagrams have come, at most `timeout` s."""
        async with asyncio.timeout(timeout):
            while sum(len(d) for _, d in self.calls) < count:
                self.changed.clear()
                await self.changed.wait()


def send(port: int, datagrams: list[bytes]) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
        for datagram in datagrams:
            sender.sendto(datagram, ("127.0.0.1", port))


async def paced_reads(port: int, interval: float, steps: list[list[bytes]]) -> list[tuple[float, list[bytes]]]:
    """A transport paced at `interval` on `port`: each step's datagrams are sent once all before
    them have come (30 s at most each); the calls it made, with their loop times."""
    transport = UdpTransport(Address("udpin", host="127.0.0.1", port=port))
    assert transport.pace_reads(lambda: interval)
    batches = Batches()
    await transport.open(lambda data: None, batches)
    try:
        sent = 0
        for datagrams in steps:
            send(port, datagrams)
            sent += len(datagrams)
            await batches.until(sent, 30)
    finally:
        transport.close()
    return batches.calls


def test_a_paced_socket_holds_what_comes_within_the_interval_for_one_read(udp_port):
    """Datagrams that come closer than two intervals apart: the second is read at once (the socket
    is watched), what comes after that read waits for the interval to end and is then handed over
    in one call, in order."""
    interval = 0.5
    # "a", "b", "c" come while the socket is held
    calls = asyncio.run(paced_reads(udp_port, interval, [[b"zero"], [b"first"], [b"a", b"b", b"c"]]))
    assert [d for _, d in calls] == [[b"zero"], [b"first"], [b"a", b"b", b"c"]]
    (zero, _), (first, _), (second, _) = calls
    assert first - zero < 2 * interval  # the case tested: a stream denser than two intervals
    assert second - first >= interval - 0.002  # held for the interval (timers fire at 1 ms steps)


def test_a_datagram_after_a_quiet_spell_starts_no_hold(udp_port):
    """The first datagram after two intervals without any (here: the first ever) is read and the
    socket kept watched: the next one is read as it comes, not after the (60 s) interval. A slow
    stream costs the loop one wake-up per datagram, not two."""
    calls = asyncio.run(paced_reads(udp_port, 60.0, [[b"alone"], [b"next"]]))
    assert [d for _, d in calls] == [[b"alone"], [b"next"]]


def test_a_full_read_is_not_held(udp_port):
    """A flood (a whole UDP_READ_BATCH in one read) is read again at once, not after the (60 s)
    interval: queued before the loop reads, it all comes within the 30 s wait."""
    flood = [k.to_bytes(2, "big") for k in range(UDP_READ_BATCH + 40)]
    calls = asyncio.run(paced_reads(udp_port, 60.0, [flood]))
    assert [d for _, call in calls for d in call] == flood
    assert len(calls[0][1]) == UDP_READ_BATCH


def test_only_a_udp_link_is_paced():
    """TCP and serial deliver a chunk per read already: their links say they are not paced, and a
    reader (the live estimation) keeps its own tick there."""
    udp = Link("udpin:127.0.0.1:14550")
    assert not udp.reads_paced
    assert udp.pace_reads(lambda: 0.01) and udp.reads_paced
    for address in ("tcp:127.0.0.1:5760", "/dev/ttyUSB0"):
        stream = Link(address)
        assert not stream.pace_reads(lambda: 0.01)
        assert not stream.reads_paced


def imu_datagram(encoder: Encoder, k: int) -> bytes:
    """A HIGHRES_IMU packet at k x 2.5 ms of vehicle time, level and still."""
    msg = mavlink.MAVLink_highres_imu_message(
        k * 2500, 0.0, 0.0, -9.81, 0.01, 0.0, 0.0, 0.2, 0.0, 0.4, 1013.0, 0.0, 0.0, 20.0, 0x1FFF
    )
    return encoder.encode(msg)


def test_the_estimation_takes_each_paced_read_in_one_turn_with_no_tick_of_its_own(udp_port):
    """On a paced link each read is the estimation's tick: its messages are estimated in the turn
    that read them, one feed per read. The estimation's own tick is 60 s here: had it kept it, every
    read after the first would wait in its queue, and `fed` would lag `read` (not a deadline: the
    turn right after each read is looked at)."""
    groups = [1, 1, 3, 1, 2]  # datagrams sent together (one read each: no await between the sends)

    async def go() -> tuple[list[tuple[int, int]], list[int]]:
        link = Link(f"udpin:127.0.0.1:{udp_port}")
        assert link.pace_reads(lambda: 0.05)
        estimation = LiveEstimation(link, tick=60.0)
        emitted: list[int] = []
        estimation.points.connect(lambda points: emitted.append(len(points)))
        tasks = [asyncio.create_task(link.run()), asyncio.create_task(estimation.run())]
        encoder, sent = Encoder(1, 1), 0
        try:
            await wait_for(lambda: link.is_open and link.bus.wants("HIGHRES_IMU"), 10, "the socket and the estimation")
            reads = link.bus.subscribe("test-reads", types=["HIGHRES_IMU"])  # after the estimation's
            seen: list[tuple[int, int]] = []  # (messages read, messages estimated) the turn after each read
            for n in groups:
                send(udp_port, [imu_datagram(encoder, sent + i) for i in range(n)])
                sent += n
                assert await reads.get(30) is not None, "the datagrams read"
                reads.drain()
                if not seen:  # the first message waits for the kernels, off the loop
                    await wait_for(lambda: estimation.messages_fed == 1, 120, "the kernels loaded")
                await asyncio.sleep(0)  # the estimation's turn: woken by the same read, before this task
                seen.append((reads.delivered, estimation.messages_fed))
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
        return seen, emitted

    seen, emitted = asyncio.run(go())
    read = [sum(groups[: i + 1]) for i in range(len(groups))]
    assert seen == [(n, n) for n in read]  # every read estimated in its own turn
    assert emitted == [3 * n for n in groups]  # one feed per read, of all its messages (3 estimators each)


def test_a_link_shared_by_vehicles_is_read_at_the_shortest_interval_asked(udp_port):
    """The vehicles of a fleet heard on one link each ask for their own interval (here 0.2 s, then
    60 s): the shortest holds, whatever the order, so none gets its messages later than it asked.
    Had the last one asked held, the third datagram would wait 60 s in the held socket."""

    async def go() -> None:
        link = Link(f"udpin:127.0.0.1:{udp_port}")
        assert link.pace_reads(lambda: 0.2) and link.pace_reads(lambda: 60.0)
        reads = link.bus.subscribe("test-reads", types=["HIGHRES_IMU"])
        running = asyncio.create_task(link.run())
        encoder = Encoder(1, 1)
        try:
            await wait_for(lambda: link.is_open, 10, "the socket")
            for k in range(3):  # the second is read at once and starts a hold; the third waits it out
                send(udp_port, [imu_datagram(encoder, k)])
                assert await reads.get(30) is not None, f"datagram {k} read"
        finally:
            running.cancel()
            await asyncio.gather(running, return_exceptions=True)

    asyncio.run(go())


class WatchCountingLoop(asyncio.SelectorEventLoop):
    """asyncio's own loop, counting the watches put on a socket (each an epoll_ctl, and with the
    hold's removal a second one)."""

    def __init__(self) -> None:
        super().__init__()
        self.watches = 0

    def add_reader(self, fd, callback, *args) -> None:  # type: ignore[no-untyped-def]
        self.watches += 1
        super().add_reader(fd, callback, *args)


def test_a_steady_stream_is_read_on_the_hold_timer_without_watching_the_socket_again(udp_port):
    """Datagrams every 10 ms, paced at 50 ms: after the first hold each read holds again, so the
    stream is read once per interval on the timer alone; the socket is watched at the open and
    once more when the stream stops (a read that finds nothing), not again at every interval."""
    interval, count, every = 0.05, 60, 0.01

    async def go() -> tuple[int, list[tuple[float, list[bytes]]]]:
        loop = asyncio.get_running_loop()
        assert isinstance(loop, WatchCountingLoop)
        transport = UdpTransport(Address("udpin", host="127.0.0.1", port=udp_port))
        transport.pace_reads(lambda: interval)
        batches = Batches()
        await transport.open(lambda data: None, batches)
        sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            for k in range(count):
                loop.call_later(k * every, sender.sendto, k.to_bytes(2, "big"), ("127.0.0.1", udp_port))
            await batches.until(count, 30)
            # the read after the last one finds nothing and watches the socket again
            await wait_for(lambda: loop.watches >= 2, 10, "the socket watched again once the stream stopped")
        finally:
            sender.close()
            transport.close()
        return loop.watches, batches.calls

    with asyncio.Runner(loop_factory=WatchCountingLoop) as runner:
        watches, calls = runner.run(go())
    assert [d for _, call in calls for d in call] == [k.to_bytes(2, "big") for k in range(count)]
    assert len(calls) >= 5  # read in several paced reads, not in one
    assert watches <= 3, (watches, len(calls))  # the open, the stop; one to spare for a late timer
