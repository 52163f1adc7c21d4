"""Behind (a flood, a starved machine), the live estimation works through its backlog a batch per
turn of the event loop, so the link goes on reading the socket in between; every message is still
estimated, in order."""

from __future__ import annotations

import asyncio
import threading

import pyarrow.compute as pc
import pyarrow.parquet as pq
from live import running_sim, running_station, wait_for

from gcs.mavlink.dialect import MARKER_V2, Encoder, mavlink
from gcs.mavlink.tlog import read_tlog_records
from gcs.runtime import estimation
from gcs.runtime.bus import Message
from gcs.runtime.estimation import BATCH, STARTING, TICK, LiveEstimation, warm
from gcs.runtime.link import Link
from gcs.runtime.station import Station, StationConfig
from gcs.server.app import follow
from gcs.server.live import LiveHub
from gcs.sessions import layout


def imu(encoder: Encoder, k: int) -> Message:
    msg = mavlink.MAVLink_highres_imu_message(
        k * 2500, 0.0, 0.0, -9.81, 0.01, 0.0, 0.0, 0.2, 0.0, 0.4, 1013.0, 0.0, 0.0, 20.0, 0x1FFF
    )
    encoder.encode(msg)
    return Message.of(msg, 0.0, 0.0)


def msgid(packet: bytes) -> int:
    return packet[7] | packet[8] << 8 | packet[9] << 16 if packet[0] == MARKER_V2 else packet[5]


def test_a_backlog_is_estimated_a_batch_per_turn_of_the_loop():
    async def scenario():
        link = Link("udpin:127.0.0.1:9")  # never run: the test publishes on its bus
        estimation = LiveEstimation(link)
        task = asyncio.create_task(estimation.run())
        encoder = Encoder(1, 1)
        await wait_for(lambda: link.bus.wants("HIGHRES_IMU"), 10, "the estimation's subscription")
        link.bus.publish(imu(encoder, 1))
        await wait_for(lambda: estimation.messages_fed == 1, 120, "the kernels loaded, the first message")
        backlog = 10 * BATCH
        for k in range(backlog):
            link.bus.publish(imu(encoder, k + 2))
        turns = []
        while estimation.messages_fed < 1 + backlog:
            await asyncio.sleep(0)  # one turn of the loop for everyone else (the link reading)
            turns.append(estimation.messages_fed)
        task.cancel()
        return turns

    turns = asyncio.run(scenario())
    assert turns[0] == 1 + BATCH  # the first turn took one batch, not the whole backlog
    assert len(turns) >= 10 and turns[-1] == 1 + 10 * BATCH


def test_messages_arriving_within_a_tick_are_estimated_together():
    """Datagrams each wake the loop alone; those that arrive within a tick of the last estimated
    turn wait for it and are estimated in one turn, with one call of the points' listeners."""

    async def scenario():
        link = Link("udpin:127.0.0.1:9")  # never run: the test publishes on its bus
        estimation = LiveEstimation(link, tick=1.0)  # far longer than the test's turns take
        emitted: list[int] = []
        estimation.points.connect(lambda points: emitted.append(len(points)))
        task = asyncio.create_task(estimation.run())
        encoder = Encoder(1, 1)
        await wait_for(lambda: link.bus.wants("HIGHRES_IMU"), 10, "the estimation's subscription")
        link.bus.publish(imu(encoder, 1))
        await wait_for(lambda: estimation.messages_fed == 1, 120, "the kernels loaded, the first message")
        fed = []
        for k in range(8):  # one message per turn of the loop, as datagrams arrive
            link.bus.publish(imu(encoder, k + 2))
            await asyncio.sleep(0)
            fed.append(estimation.messages_fed)
        await wait_for(lambda: estimation.messages_fed == 9, 30, "the tick's messages")
        task.cancel()
        return fed, emitted

    fed, emitted = asyncio.run(scenario())
    assert fed == [1] * 8  # none estimated on its own turn
    assert len(emitted) == 2 and emitted[1] == 8 * 3  # the first alone, then the 8 in one call (3 estimators)


def test_the_dashboard_paces_the_estimation_by_its_frame_interval():
    """The tick follows the live hub's frame interval: the estimation neither delays a frame nor
    turns more often than frames go out."""
    station = Station(StationConfig(connect="udpin:127.0.0.1:9", request_streams=False))
    hub = LiveHub()
    assert station.estimation is not None and station.estimation.tick() == TICK
    follow(station, hub)
    assert station.estimation.tick() == hub.flush_interval() == 0.015
    hub.frame_interval = 0.004
    assert station.estimation.tick() == 0.004


def test_a_stopped_session_holds_the_estimates_of_every_input_it_recorded(tmp_path, udp_port):
    """Inputs recorded in the session's tlog but still waiting for the estimation's next tick
    when the recording stops are estimated into that session: `gcs estimate` on its tlog and the
    live attitude it holds then cover the same samples."""

    async def scenario():
        async with running_station(f"udpin:127.0.0.1:{udp_port}", sessions_dir=str(tmp_path), record=True) as station:
            estimation = station.estimation
            assert estimation is not None
            estimation.pace(lambda: 5.0)  # far longer than the test: what arrives after the first turn waits
            encoder = Encoder(1, 1)
            await wait_for(lambda: station.bus.wants("HIGHRES_IMU"), 10, "the estimation's subscription")
            station.bus.publish(imu(encoder, 1))
            await wait_for(lambda: estimation.messages_fed == 1, 120, "the kernels loaded, the first message")
            for k in range(40):
                station.bus.publish(imu(encoder, k + 2))
                await asyncio.sleep(0)
            waiting = 41 - estimation.messages_fed
            await station.stop_recording("test")
            return waiting, [p for p in tmp_path.iterdir() if layout.is_session(p)]

    waiting, (folder,) = asyncio.run(scenario())
    assert waiting == 40  # all of them were waiting for the tick when the recording stopped
    recorded = sum(1 for _, packet in read_tlog_records(folder / layout.TLOG) if msgid(packet) == 105)  # HIGHRES_IMU
    attitude = pq.read_table(folder / "attitude.parquet")
    dcm = attitude.filter(pc.equal(attitude["source"], "dcm")).num_rows
    assert recorded == 41 and dcm == recorded


def test_while_the_kernels_load_the_estimators_say_so_not_a_missing_imu(monkeypatch, udp_port):
    """The first start after an install compiles the kernels for a minute or more; meanwhile the
    IMU arrives and waits. The estimators' reason says they are starting (it said "raw IMU at
    0.0 Hz ... request RAW_IMU at 50 Hz", which sent the engineer after the wrong problem); once
    loaded, the waiting samples are estimated and the reason is the estimators' own again."""
    compiled = threading.Event()

    def slow_warm() -> None:  # the compilation: until the test lets it finish, then the real load
        compiled.wait(60)
        warm()

    monkeypatch.setattr(estimation, "warm", slow_warm)

    async def scenario():
        async with (
            running_station(f"udpin:127.0.0.1:{udp_port}") as station,
            running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk"),
        ):
            counts = station.link.stats.counts
            await wait_for(
                lambda: counts.get("RAW_IMU", 0) + counts.get("HIGHRES_IMU", 0) > 100, 30, "the IMU arriving"
            )
            starting = station.publish().estimation
            compiled.set()
            await wait_for(lambda: station.estimation.pipeline.imu_samples > 100, 60, "the waiting samples estimated")
            return starting, station.publish().estimation

    starting, started = asyncio.run(scenario())
    assert starting is not None and started is not None
    assert {e.reason for e in starting.estimators.values()} == {STARTING}
    assert not any(e.reliable for e in starting.estimators.values())
    assert all(e.reason != STARTING for e in started.estimators.values())
