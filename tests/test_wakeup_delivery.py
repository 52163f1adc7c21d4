"""Delivery per wake-up (issue 17): the datagrams one wake-up of a UDP socket read go to the link in
one call (`Link._on_datagrams`), are framed in one pass, published in one call per run up to each
HEARTBEAT, handed to a served vehicle's view in one call, and the live estimation turns IMU packets
straight into their batch rows (`MessageInputs.feed_imu`). Everything must be what the per-datagram
path gives with the same stamps: every subscriber's messages (bytes, stamps, order, what was read),
drops, link and vehicle counters, framing counters, the tlog records, the estimation's inputs (the
floats bit for bit, in order, with the vehicle clock and the declination) and the attitudes, on
real streams (the ArduCopter SITL tlog in MAVLink 2, the ArduPlane one in MAVLink 1, the serve
bench's stream from two vehicles) and on damaged datagrams."""

from __future__ import annotations

import asyncio
import dataclasses
import math
import random
import socket
from types import SimpleNamespace
from typing import Any

import pytest
from exact import bits

from bench.serve_cpu import packets as serve_stream
from bench.serve_cpu import stream_message
from gcs.core.estimation import AttitudePoint, EstimationPipeline
from gcs.core.estimators.stepping import ImuBatch, imu_sample_of
from gcs.core.samples import ImuSample
from gcs.mavlink.dialect import Encoder, mavlink
from gcs.mavlink.sampling import INPUT_TYPES, MessageInputs
from gcs.mavlink.tlog import read_tlog_records, tlog_record, tlog_wall_time
from gcs.runtime import link as link_module
from gcs.runtime.bus import Message, MessageBus, Subscription
from gcs.runtime.estimation import LiveEstimation
from gcs.runtime.fleet import Fleet, VehicleEntry
from gcs.runtime.link import Link
from gcs.runtime.recorder import RECEIVED, TlogClock
from gcs.runtime.station import StationConfig
from gcs.runtime.vehicle import OBSERVED_TYPES
from gcs.transport.address import Address
from gcs.transport.pipes import UDP_READ_BATCH, UdpTransport


def wakeups(datagrams: list[bytes], seed: int) -> list[list[bytes]]:
    """The datagrams as the wake-ups of a socket might read them: 1 to 40 at a time, some alone."""
    rng = random.Random(seed)
    out, i = [], 0
    while i < len(datagrams):
        n = 1 if rng.random() < 0.2 else rng.randrange(1, 41)
        out.append(datagrams[i : i + n])
        i += n
    return out


class SpyPipeline(EstimationPipeline):
    """The real pipeline, keeping what the live estimation fed it."""

    def __init__(self) -> None:
        super().__init__()
        self.fed: list[Any] = []

    def feed_many(self, items):  # type: ignore[no-untyped-def]
        self.fed += items
        return super().feed_many(items)


def imu_row(sample: ImuSample) -> tuple[float, ...]:
    return tuple(ImuBatch.of([sample]).rows[0].tolist())


def normal(item: object) -> object:
    """An estimation input as compared: an IMU sample as its batch row, whichever form it came in."""
    if isinstance(item, ImuSample):
        return "imu", bits(imu_row(item))
    if isinstance(item, tuple):
        return "imu", bits(item)
    return bits(item)


@dataclasses.dataclass
class Run:
    """What one path gave: per subscription its messages, drops and deliveries; the counters."""

    subscriptions: dict[str, list[tuple]] = dataclasses.field(default_factory=dict)
    counters: dict[str, object] = dataclasses.field(default_factory=dict)
    tlog: bytes = b""
    inputs: list[object] = dataclasses.field(default_factory=list)
    points: list[AttitudePoint] = dataclasses.field(default_factory=list)
    input_clock: object = None


def seen(item: Message) -> tuple:
    imu = None if item.imu is None else (item.imu.type, item.imu.sysid, bits(item.imu.t), bits(item.imu.axes))
    return item.raw, item.type, bits(item.host_time), bits(item.wall_time), item.sysid, item.compid, item.link, imu


def link_counters(link: Link) -> dict[str, object]:
    stats = link.stats
    return {
        "counts": dict(stats.counts),
        "bytes_in": stats.bytes_in,
        "nonfinite": dict(stats.nonfinite),
        "framing": dataclasses.asdict(stats.framing),
        "state": str(link.state),
        "target": (link.target_system, link.target_component, link.vehicle_mavlink),
        "heard": dict(link.vehicles_heard),
        "events": [(e.kind, e.detail) for e in link.events],
    }


def bus_counters(bus: MessageBus) -> tuple[int, int]:
    return bus.published, bus.inputs_published


def deliver(batches: list[list[bytes]], batched: bool, fleet: bool, monkeypatch: pytest.MonkeyPatch) -> Run:
    """The batches through a real link (a fleet's, serving every vehicle heard, or a lone one) with
    every datagram of a batch stamped alike, the station's parts subscribed as they are live; the
    first vehicle's estimation fed per message (`MessageInputs.feed`, then `feed` per input) or as
    the live estimation feeds it (`LiveEstimation._feed`, `feed_many`)."""
    stamp = {"mono": 0.0, "wall": 0.0}
    monkeypatch.setattr(
        link_module, "time", SimpleNamespace(monotonic=lambda: stamp["mono"], time=lambda: stamp["wall"])
    )
    run = Run()

    async def go() -> None:
        subs: dict[str, Subscription] = {}

        def subscribe(prefix: str, bus: MessageBus) -> None:
            subs[prefix + "estimation"] = bus.subscribe("estimation", types=INPUT_TYPES, maxlen=1_000_000)
            subs[prefix + "vehicle-state"] = bus.subscribe("vehicle-state", types=OBSERVED_TYPES, maxlen=1_000_000)
            subs[prefix + "recorder"] = bus.subscribe("recorder", maxlen=1_000_000)
            subs[prefix + "slow, every type"] = bus.subscribe("slow", maxlen=7)  # drops in a long wake-up
            subs[prefix + "slow, replies"] = bus.subscribe("replies", types=["HEARTBEAT", "PARAM_VALUE"], maxlen=2)

        if fleet:
            the_fleet = Fleet(StationConfig(connect="udpin:127.0.0.1:9"))
            link = the_fleet.links[0]
            first = the_fleet.first
            subscribe("", first.bus)
            views = {"": first.link}

            def added(entry: VehicleEntry) -> None:
                if entry.station is not first:
                    subscribe(f"{entry.sysid}:", entry.station.bus)
                    views[f"{entry.sysid}:"] = entry.station.link

            the_fleet.vehicle_added.connect(added)
            estimated = first.link
        else:
            link = Link("udpin:127.0.0.1:9")
            subscribe("", link.bus)
            views = {}
            estimated = link
        per_message, reference = MessageInputs(), EstimationPipeline()
        spy = SpyPipeline()
        live = LiveEstimation(estimated, spy)
        live.points.connect(run.points.extend)
        clock = TlogClock()
        tlog: list[bytes] = []
        for k, batch in enumerate(batches):
            stamp["mono"], stamp["wall"] = 1000.0 + k * 0.0025, 1.7e9 + k * 0.0025
            if batched:
                link._on_datagrams(batch)
            else:
                for datagram in batch:
                    link._on_data(datagram)
            for name, sub in subs.items():  # the loop's turn after the wake-up
                items = sub.drain()
                run.subscriptions.setdefault(name, []).extend(seen(item) for item in items)
                if name == "recorder":
                    tlog += [tlog_record(clock.stamp(item.wall_time, RECEIVED), item.raw) for item in items]
                if name != "estimation":
                    continue
                if batched:
                    live._feed(items)
                else:
                    for item in items:
                        inputs = per_message.feed(item.reading, tlog_wall_time(item.wall_time))
                        run.inputs += inputs
                        for one in inputs:
                            run.points += reference.feed(one)
        for name, sub in subs.items():
            run.subscriptions[name].append(("dropped", sub.dropped, "delivered", sub.delivered))
        run.counters["link"] = link_counters(link)
        run.counters["link bus"] = bus_counters(link.bus)
        for prefix, view in views.items():
            run.counters[prefix + "view"] = link_counters(view)
            run.counters[prefix + "view bus"] = bus_counters(view.bus)
        run.tlog = b"".join(tlog)
        inputs_used = live.inputs if batched else per_message
        if batched:
            run.inputs = spy.fed
        run.input_clock = (
            bits(tuple(sorted(inputs_used.sampler.clock.latest.items()))),
            inputs_used.sampler.imu_type,
            inputs_used.declination_source,
            bits(inputs_used.declination),
        )

    asyncio.run(go())
    return run


def assert_same(batched: Run, per_datagram: Run) -> None:
    assert batched.counters == per_datagram.counters
    assert batched.subscriptions.keys() == per_datagram.subscriptions.keys()
    for name in per_datagram.subscriptions:
        assert batched.subscriptions[name] == per_datagram.subscriptions[name], name
    assert batched.tlog == per_datagram.tlog
    assert [normal(x) for x in batched.inputs] == [normal(x) for x in per_datagram.inputs]
    assert batched.input_clock == per_datagram.input_clock
    assert [bits(p) for p in batched.points] == [bits(p) for p in per_datagram.points]


def tlog_datagrams(path, limit: int | None = None) -> list[bytes]:
    return [packet for k, (_, packet) in enumerate(read_tlog_records(path)) if limit is None or k < limit]


@pytest.mark.parametrize("fleet", [True, False], ids=["fleet", "link"])
@pytest.mark.parametrize(
    ("name", "marker"), [("arducopter-sitl-hop.tlog", 0xFD), ("arduplane-sitl-vtol.tlog", 0xFE)], ids=["v2", "v1"]
)
def test_a_real_tlog_delivered_per_wakeup_gives_what_per_datagram_gives(logs_dir, monkeypatch, name, marker, fleet):
    datagrams = tlog_datagrams(logs_dir / name)
    assert sum(d[0] == marker for d in datagrams) > 0.9 * len(datagrams)  # MAVLink 2 / MAVLink 1
    batches = wakeups(datagrams, 17)
    per_datagram = deliver(batches, False, fleet, monkeypatch)
    batched = deliver(batches, True, fleet, monkeypatch)
    assert_same(batched, per_datagram)
    imu = [x for x in batched.inputs if isinstance(x, tuple)]
    samples = [x for x in per_datagram.inputs if isinstance(x, ImuSample)]
    assert len(imu) > 700 and len(imu) >= len(samples) - 5  # rows, but where the stream is being chosen
    assert {type(x).__name__ for x in batched.inputs} >= {"tuple", "AttitudeSample", "GpsSample"}
    assert len(batched.points) > 2000
    # a row stands for the sample the per-message path builds (where a part needs the sample)
    rows_at = [k for k, x in enumerate(batched.inputs) if isinstance(x, tuple)][:500]
    for k in rows_at:
        row, sample = batched.inputs[k], per_datagram.inputs[k]
        assert bits(dataclasses.replace(imu_sample_of(row), source=sample.source)) == bits(sample)
    counts = per_datagram.counters["link"]["counts"]  # type: ignore[index]
    assert sum(counts.values()) > 10_000


def two_vehicles(seconds: float) -> list[bytes]:
    """The serve bench's stream from vehicle 1 and the same mix from vehicle 2 (its own clock),
    interleaved as two senders' datagrams arrive at one port."""
    enc = Encoder(2, 1)
    second = []
    for name, hz in (("HIGHRES_IMU", 400), ("ATTITUDE", 100), ("GPS_RAW_INT", 5), ("HEARTBEAT", 1)):
        period = 1.0 / hz
        for k in range(int(seconds / period)):
            second.append((k * period + 0.0007, enc.encode(stream_message(name, int(k * 1e6 / hz) + 333))))
    merged = sorted([*serve_stream(1000, seconds), *second], key=lambda p: p[0])
    return [p for _, p in merged]


def test_two_vehicles_on_one_port_delivered_per_wakeup(monkeypatch):
    batches = wakeups(two_vehicles(4.0), 5)
    per_datagram = deliver(batches, False, True, monkeypatch)
    batched = deliver(batches, True, True, monkeypatch)
    assert_same(batched, per_datagram)
    assert "2:estimation" in batched.subscriptions  # the second vehicle got its own core
    highres = [s for s in batched.subscriptions["2:estimation"] if s[1:2] == ("HIGHRES_IMU",)]
    assert len(highres) > 1000 and all(s[4] == 2 for s in highres)
    assert all(s[4] == 1 for s in batched.subscriptions["estimation"][:-1])
    assert sum(isinstance(x, tuple) for x in batched.inputs) > 1000


def damaged(datagrams: list[bytes], seed: int) -> list[bytes]:
    """Truncated packets, flipped bits, garbage before a packet, two packets in one datagram, empty
    and all-garbage datagrams, and HIGHRES_IMU with a non-finite axis."""
    rng = random.Random(seed)
    enc = Encoder(1, 1, mavlink1=False)
    out: list[bytes] = []
    for k, packet in enumerate(datagrams):
        cut = rng.random()
        if cut < 0.03:
            packet = packet[: rng.randrange(1, len(packet))]
        elif cut < 0.06:
            flipped = bytearray(packet)
            flipped[rng.randrange(len(flipped))] ^= 1 << rng.randrange(8)
            packet = bytes(flipped)
        elif cut < 0.08:
            packet = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 30))) + packet
        elif cut < 0.10 and k + 1 < len(datagrams):
            packet = packet + datagrams[k + 1]  # two in one
        elif cut < 0.11:
            out.append(b"")
        elif cut < 0.12:
            out.append(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 80))))
        elif cut < 0.13:
            axes = [0.05, -0.03, -9.8, 0.01, -0.02, 0.005, 0.21, 0.02, 0.42]
            axes[rng.randrange(9)] = rng.choice([math.nan, math.inf, -math.inf])
            out.append(enc.encode(mavlink.MAVLink_highres_imu_message(k, *axes, 1000.0, 0, 0, 25.0, 0x1FFF, 0)))
        out.append(packet)
    return out


@pytest.mark.parametrize("fleet", [True, False], ids=["fleet", "link"])
def test_damaged_datagrams_delivered_per_wakeup(logs_dir, monkeypatch, fleet):
    datagrams = damaged(tlog_datagrams(logs_dir / "arducopter-sitl-hop.tlog", 6000), 3)
    datagrams += damaged([p for _, p in serve_stream(1000, 3.0)], 4)
    batches = wakeups(datagrams, 11)
    per_datagram = deliver(batches, False, fleet, monkeypatch)
    batched = deliver(batches, True, fleet, monkeypatch)
    assert_same(batched, per_datagram)
    framing = batched.counters["link"]["framing"]  # type: ignore[index]
    assert (
        framing["crc_errors"] > 100
        and framing["bytes_skipped"] > 1000
        and framing["malformed"] + framing["unknown"] > 0
    )
    assert batched.counters["link"]["nonfinite"]["HIGHRES_IMU"] > 10  # type: ignore[index]


def test_a_state_change_sees_what_came_before_its_heartbeat(monkeypatch):
    """The recorder drains before it records a packet the station sends, and a state change may
    send one: the messages before the heartbeat are published before it is read, as per datagram."""
    enc = Encoder(1, 1)
    imu = [enc.encode(stream_message("HIGHRES_IMU", k * 2500)) for k in range(6)]
    beat = enc.encode(stream_message("HEARTBEAT", 0))

    async def go() -> tuple[list[list[str]], list[list[str]]]:
        fleet = Fleet(StationConfig(connect="udpin:127.0.0.1:9"))
        link, view = fleet.links[0], fleet.first.link
        recorder = fleet.first.bus.subscribe("recorder", maxlen=100)
        own = link.bus.subscribe("a tool on the link", maxlen=100)
        at_link: list[list[str]] = []
        at_view: list[list[str]] = []
        link.state_changed.connect(lambda old, new: at_link.append([m.type for m in own.drain()]))
        view.state_changed.connect(lambda old, new: at_view.append([m.type for m in recorder.drain()]))
        link._on_datagrams([imu[0], imu[1], beat, imu[2], imu[3]])
        return at_link, at_view

    at_link, at_view = asyncio.run(go())
    assert at_link == [["HIGHRES_IMU", "HIGHRES_IMU"]]
    # the first vehicle is adopted at its heartbeat: before it, its core got everything unbound
    assert at_view == [["HIGHRES_IMU", "HIGHRES_IMU"]]


def test_a_udp_wakeup_hands_over_every_datagram_in_one_call(udp_port):
    """A real socket: what waits is read in one wake-up (up to UDP_READ_BATCH) and handed over in one
    on_batch call, in order; without on_batch, one on_data call per datagram."""

    async def go(batched: bool) -> tuple[list[list[bytes]], list[bytes]]:
        transport = UdpTransport(Address("udpin", host="127.0.0.1", port=udp_port))
        calls: list[list[bytes]] = []
        single: list[bytes] = []
        loop = asyncio.get_running_loop()
        got_all = loop.create_future()
        # fewer than a default 208 KB receive buffer holds (rmem_max caps what the transport asks)
        sent = [bytes([k % 256]) * (1 + k % 50) for k in range(120)]

        def on_batch(datagrams: list[bytes]) -> None:
            calls.append(list(datagrams))
            if sum(map(len, calls)) == len(sent) and not got_all.done():
                got_all.set_result(None)

        def on_data(data: bytes) -> None:
            single.append(data)
            if len(single) == len(sent) and not got_all.done():
                got_all.set_result(None)

        await transport.open(on_data, on_batch if batched else None)
        sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            for datagram in sent:  # all queued before the loop runs the reader again
                sender.sendto(datagram, ("127.0.0.1", udp_port))
            async with asyncio.timeout(20):
                await got_all
        finally:
            sender.close()
            transport.close()
        assert [d for call in calls for d in call] == (sent if batched else [])
        assert single == ([] if batched else sent)
        return calls, single

    calls, _ = asyncio.run(go(True))
    assert max(map(len, calls)) <= UDP_READ_BATCH and len(calls) < 10  # a wake-up's reads together
    asyncio.run(go(False))
