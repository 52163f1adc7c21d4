"""When the live hub flushes its pending frame (gcs.server.live): new data goes out in the loop's
next turn once the last flush is old enough, data arriving sooner is held and sent in one frame,
the interval keeps the fan-out within its send budget, and no sample is lost or sent twice on
the way, whatever the bursts; a viewer's counters and the data age as GET /api/status lists
them. No timing is asserted: only what was sent, and in which turn (the hub's clock, where the
gap matters, is the test's)."""

from __future__ import annotations

import asyncio
import dataclasses
import random

from gcs.core.estimation import AttitudePoint
from gcs.server import wire
from gcs.server.client_feed import ClientFeed, ClientSnapshot
from gcs.server.live import LiveHub


def point(t: float, source: str = "onboard") -> AttitudePoint:
    return AttitudePoint(t, source, 0.1, -0.2, 0.3)


class Clock:
    """The hub's clock, moved by the test: the time a flush waits for passes at once, whatever
    the load (the loop's own timers still run on real time)."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def decoded(feed: ClientFeed) -> list[wire.PointsFrame]:
    frames = feed.frames.drain()
    return [f for data, _ in frames for f in wire.decode(data) if isinstance(f, wire.PointsFrame)]


def test_new_data_goes_out_in_the_next_turn_when_the_last_flush_is_old():
    async def run() -> tuple[int, list[wire.PointsFrame]]:
        hub = LiveHub(seconds=10)
        feed = hub.connect("test")
        hub.on_points([point(1.0)])
        await asyncio.sleep(0)  # one turn of the loop
        return hub.frames_out, decoded(feed)

    frames_out, frames = asyncio.run(run())
    assert frames_out == 1
    assert [f.points["onboard"][0] for f in frames] == [(1.0,)]


def test_data_arriving_within_the_interval_is_held_and_sent_in_one_frame():
    async def run() -> tuple[int, list[wire.PointsFrame]]:
        hub = LiveHub(seconds=10)
        feed = hub.connect("test")
        hub.on_points([point(1.0)])
        await asyncio.sleep(0)
        # an interval no loaded machine outlasts between two lines; broadcast then sends what is held
        hub.frame_interval = 3600.0
        hub.on_points([point(1.005)])
        hub.on_points([point(1.01), point(1.0, "dcm")])
        await asyncio.sleep(0)
        held = hub.frames_out  # the first frame only: the rest waits for the interval
        hub.broadcast({"type": "gain"})
        return held, decoded(feed)

    held, frames = asyncio.run(run())
    assert held == 1
    first, second = frames
    assert first.points["onboard"][0] == (1.0,)
    assert second.points["onboard"][0] == (1.005, 1.01) and second.points["dcm"][0] == (1.0,)


def test_a_turn_that_comes_a_little_early_goes_out_at_once_and_one_much_sooner_waits():
    """The points come paced by the interval already: a turn more than half an interval after the
    last frame is not held for the rest of it (a timer, and latency); one sooner is."""

    async def run(elapsed: float) -> int:
        clock = Clock()
        hub = LiveHub(seconds=10, frame_interval=3600.0, clock=clock)
        hub.connect("test")
        hub.on_points([point(1.0)])
        await asyncio.sleep(0)
        clock.now += elapsed * 3600.0  # that much of the interval has passed since the flush
        hub.on_points([point(1.01)])
        await asyncio.sleep(0)
        return hub.frames_out

    assert asyncio.run(run(0.9)) == 2
    assert asyncio.run(run(0.6)) == 2
    assert asyncio.run(run(0.4)) == 1


def test_a_frame_every_15_ms_whether_one_page_five_or_none_is_open():
    """One page used to get 4 ms frames, and cost the station more than five pages did (the link's
    reads and the estimation's ticks follow the interval)."""
    hub = LiveHub(seconds=10)
    assert hub.flush_interval() == 0.015
    feeds = [hub.connect(str(k)) for k in range(5)]
    assert hub.flush_interval() == 0.015
    for feed in feeds[1:]:
        hub.disconnect(feed)
    assert hub.flush_interval() == 0.015


def test_without_clients_nothing_is_encoded_and_the_store_keeps_everything():
    async def run() -> tuple[int, int, list[wire.PointsFrame]]:
        hub = LiveHub(seconds=10, frame_interval=0.0)
        hub.on_points([point(1.0), point(1.005)])
        await asyncio.sleep(0)
        before = hub.frames_out
        feed = hub.connect("late")
        hub.on_points([point(1.01)])
        async with asyncio.timeout(30):
            await feed.frames.wait()
        return before, hub.store["onboard"].count, decoded(feed)

    before, stored, frames = asyncio.run(run())
    assert before == 0 and stored == 3
    assert [f.points["onboard"][0] for f in frames] == [(1.01,)]  # the earlier ones are history's


def test_every_sample_reaches_a_reading_client_once_and_in_order():
    rng = random.Random(17)
    sources = ("onboard", "dcm", "kf", "ekf")
    sent: dict[str, list[float]] = {s: [] for s in sources}

    async def run() -> tuple[dict[str, list[float]], int]:
        hub = LiveHub(seconds=60, frame_interval=0.002)
        feed = hub.connect("reader")
        got: dict[str, list[float]] = {s: [] for s in sources}
        total = 0

        async def read() -> None:
            received = 0
            while received < total:
                await feed.frames.wait()
                message, points = feed.take()
                received += points
                for frame in wire.decode(message):
                    assert isinstance(frame, wire.PointsFrame)
                    for source, cols in frame.points.items():
                        got[source] += cols[0]

        t = 10.0
        for _ in range(400):  # bursts of 0-12 points, the loop turning 0-2 times between them
            burst = []
            for _ in range(rng.randrange(13)):
                t += 0.0025
                source = rng.choice(sources)
                sent[source].append(round(t, 6))
                burst.append(point(t, source))
            total += len(burst)
            if burst:
                hub.on_points(burst)
            for _ in range(rng.randrange(3)):
                await asyncio.sleep(0)
        async with asyncio.timeout(60):
            await read()
        return got, feed.dropped_points

    got, dropped = asyncio.run(run())
    assert dropped == 0
    assert sum(map(len, sent.values())) > 1000
    for source in sources:
        assert got[source] == sent[source], source


def test_the_data_age_is_the_hub_clocks_time_since_the_newest_point():
    async def run() -> tuple[float | None, float | None]:
        clock = Clock()
        hub = LiveHub(seconds=10, clock=clock)
        before = hub.data_age()
        hub.on_points([point(1.0)])
        clock.now += 0.25
        return before, hub.data_age()

    assert asyncio.run(run()) == (None, 0.25)


def test_a_viewers_counters_as_the_status_lists_them():
    async def run() -> list[tuple[ClientSnapshot, dict]]:
        hub = LiveHub(seconds=10, client_max_frames=2)
        reading, stuck = hub.connect("127.0.0.1:1"), hub.connect("127.0.0.1:2")
        for k in range(3):
            hub.broadcast({"type": "gain", "k": k})
        await reading.frames.wait()
        reading.take()
        reading.sent(0)
        return [(c.snapshot(), c.snapshot().as_dict()) for c in (reading, stuck)]

    (reading_snapshot, reading), (stuck_snapshot, stuck) = asyncio.run(run())
    assert reading == dataclasses.asdict(reading_snapshot) and stuck == dataclasses.asdict(stuck_snapshot)
    assert reading["sent_messages"] == 1 and reading["queued_frames"] == 0
    assert stuck["dropped_frames"] == 1 and stuck["queued_frames"] == 2 and stuck["address"] == "127.0.0.1:2"


class Gate:
    """A client's writer whose sends wait while the gate is shut, as a send to a client whose
    transport is paused waits for it to drain; with the gate open a send finishes without
    waiting, as one the socket accepts at once."""

    def __init__(self, open_: bool = True) -> None:
        self.opened = asyncio.Event()
        if open_:
            self.opened.set()
        self.messages: list[bytes] = []

    async def write(self, message: bytes) -> None:
        await self.opened.wait()
        self.messages.append(message)

    def onboard_times(self) -> list[float]:
        return [
            t
            for m in self.messages
            for f in wire.decode(m)
            if isinstance(f, wire.PointsFrame)
            for t in f.points["onboard"][0]
        ]


def test_a_frame_is_written_in_the_flushs_own_turn_when_the_client_keeps_up():
    async def run() -> tuple[list[float], int, int]:
        hub = LiveHub(seconds=10, frame_interval=0.0)
        reader = Gate()
        hub.connect("reader").attach(reader.write)
        hub.on_points([point(1.0)])
        await asyncio.sleep(0)  # the flush's turn
        written = reader.onboard_times()  # nothing else ran after the flush: no task was woken
        return written, len(asyncio.all_tasks()), hub.clients[1].sent_messages

    written, tasks, sent = asyncio.run(run())
    assert written == [1.0] and sent == 1
    assert tasks == 1  # this test's own: the write made none


def test_a_slow_client_queues_and_drops_alone_and_gets_the_rest_in_one_message_once_it_reads():
    async def run() -> dict:
        hub = LiveHub(seconds=10, frame_interval=0.0, client_max_frames=3)
        slow, reader = Gate(open_=False), Gate()
        slow_feed = hub.connect("slow")
        slow_feed.attach(slow.write)
        hub.connect("reader").attach(reader.write)
        for k in range(6):  # 6 frames: the first waits in its send, 3 queue, 2 are dropped
            hub.on_points([point(1.0 + k)])
            await asyncio.sleep(0)
        while_stuck = (
            list(reader.onboard_times()),
            len(slow.messages),
            slow_feed.dropped_frames,
            len(slow_feed.frames),
        )
        slow.opened.set()
        async with asyncio.timeout(30):
            while slow_feed.sent_messages < 2:
                await asyncio.sleep(0)
        return {
            "while_stuck": while_stuck,
            "slow_messages": len(slow.messages),
            "slow_times": slow.onboard_times(),
            "dropped_points": slow_feed.dropped_points,
            "queued_points": slow_feed.queued_points,
        }

    r = asyncio.run(run())
    reader_times, slow_written, dropped, queued = r["while_stuck"]
    assert reader_times == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]  # the reader never waited for the slow one
    assert slow_written == 0 and dropped == 2 and queued == 3
    # its first frame, then the newest three in one message; the two oldest queued were dropped
    assert r["slow_messages"] == 2 and r["slow_times"] == [1.0, 4.0, 5.0, 6.0]
    assert r["dropped_points"] == 2 and r["queued_points"] == 0


def test_a_client_whose_write_fails_is_sent_nothing_more_and_the_others_go_on():
    async def broken(message: bytes) -> None:
        raise ConnectionResetError("the client went away")

    async def run() -> tuple[list[float], bool, int]:
        hub = LiveHub(seconds=10, frame_interval=0.0)
        gone, reader = hub.connect("gone"), Gate()
        gone.attach(broken)
        hub.connect("reader").attach(reader.write)
        for k in range(3):
            hub.on_points([point(1.0 + k)])
            await asyncio.sleep(0)
        return reader.onboard_times(), gone.closed, len(gone.frames)

    times, closed, queued = asyncio.run(run())
    assert times == [1.0, 2.0, 3.0] and closed and queued == 0
