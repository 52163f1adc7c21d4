"""Messages/s decoded and dispatched by the link + bus, as a ratio to a bare pymavlink parse
loop over the same bytes in the same run.

Baseline `pymavlink`: `MAVLink.parse_buffer` plus `get_type()` per message (the loop every
pymavlink tool runs), which decodes every packet.
- `link decode+dispatch`: `Link._on_data` on 4 KiB chunks of a mixed stream, one subscriber
  asking for every type of the stream by name (so the link decodes each one, as the baseline
  does): the resynchronising framing, per-type counters, the stamped `Message` and a publish.
- `serve receive path`: what `gcs serve` does per packet of bench.serve_cpu's stream (HIGHRES_IMU
  400 : ATTITUDE 100 : GPS 5 : HEARTBEAT 1, one packet per datagram as over UDP): a fleet's link
  routing to the vehicle's core, whose parts subscribe as they do live (the estimation and the
  vehicle state by type and reading every message, the recorder every type as bytes, the stream
  requester's replies), drained every 8 datagrams. Every message of this stream is read: the
  IMU messages (HIGHRES_IMU) from their bytes (gcs.mavlink.imu_packets), the others decoded. The
  8 datagrams go to the link in one call, as a UDP socket's wake-up hands them over
  (`Link._on_datagrams`); the `per datagram` row hands them over one by one (`Link._on_data`).
- `serve receive path to the estimation's inputs`: the same, and the estimation's messages turned
  into its inputs as the live estimation does before its estimators run (`LiveEstimation._feed`'s
  input side: an IMU packet straight to its batch row, `MessageInputs.feed_imu`, else
  `MessageInputs.feed`: samples on the vehicle's clock), and the wake-up's IMU table
  (`ImuBatch.of`). `the path before`: per datagram, an ImuSample per IMU message, its table built
  from the samples.
"""

from __future__ import annotations

import asyncio
import time

from bench.serve_cpu import packets
from gcs.core.estimation import EstimationInput
from gcs.core.estimators.stepping import ImuBatch, ImuRow
from gcs.core.samples import ImuSample
from gcs.mavlink.dialect import Encoder, MAVLink, mavlink
from gcs.mavlink.sampling import INPUT_TYPES, MessageInputs
from gcs.mavlink.tlog import tlog_wall_time
from gcs.runtime.fleet import Fleet
from gcs.runtime.link import Link
from gcs.runtime.station import StationConfig
from gcs.runtime.vehicle import OBSERVED_TYPES

CHUNK = 4096


def sample_stream(n: int = 60_000) -> bytes:
    enc = Encoder(1, 1)
    cycle = [
        lambda k: mavlink.MAVLink_raw_imu_message(k * 5000, 10, -20, -1000, 1, 2, 3, 200, -50, 400),
        lambda k: mavlink.MAVLink_scaled_imu2_message(k * 5, 11, -21, -1001, 1, 2, 3, 201, -51, 401),
        lambda k: mavlink.MAVLink_attitude_message(k * 5, 0.1, -0.2, 3.0, 0.01, 0.02, 0.03),
        lambda k: mavlink.MAVLink_ahrs2_message(0.1, 0.2, 0.3, 10.0, 71234567, -1234567),
        lambda k: mavlink.MAVLink_gps_raw_int_message(k, 3, 71234567, -1234567, 1500, 100, 100, 250, 9000, 12),
        lambda k: mavlink.MAVLink_heartbeat_message(2, 3, 81, 0, 4, 3),
    ]
    return b"".join(enc.encode(cycle[k % len(cycle)](k)) for k in range(n))


STREAM_TYPES = ("RAW_IMU", "SCALED_IMU2", "ATTITUDE", "AHRS2", "GPS_RAW_INT", "HEARTBEAT")


def chunks(data: bytes) -> list[bytes]:
    return [data[i : i + CHUNK] for i in range(0, len(data), CHUNK)]


def bare_pymavlink(parts: list[bytes]) -> int:
    mav = MAVLink(None)
    mav.robust_parsing = True
    n = 0
    for part in parts:
        for msg in mav.parse_buffer(part) or ():
            msg.get_type()
            n += 1
    return n


def link_and_bus(parts: list[bytes]) -> int:
    async def run() -> int:
        link = Link("tcp:127.0.0.1:9")  # a stream link: chunks may split packets
        sub = link.bus.subscribe("consumer", types=STREAM_TYPES, maxlen=100_000)
        for part in parts:
            link._on_data(part)
            sub.drain()
        return link.stats.framing.packets

    return asyncio.run(run())


def serve_receive_path(
    datagrams: list[bytes], wake_every: int = 8, inputs: bool = False, per_datagram: bool = False
) -> int:
    """`inputs`: the estimation's messages become its inputs too (as gcs.runtime.estimation feeds
    them), so the row runs from the datagram to the estimation's input. `per_datagram`: each
    datagram handed to the link alone."""

    async def run() -> int:
        fleet = Fleet(StationConfig(connect="udpin:127.0.0.1:9"))
        bus = fleet.first.bus
        estimation = bus.subscribe("estimation", types=INPUT_TYPES, maxlen=100_000)
        vehicle_state = bus.subscribe("vehicle-state", types=OBSERVED_TYPES, maxlen=100_000)
        recorder = bus.subscribe("recorder", maxlen=200_000)
        replies = bus.subscribe("stream-acks", types=["COMMAND_ACK", "HEARTBEAT", "STATUSTEXT", "PARAM_VALUE"])
        on_data, on_datagrams = fleet.links[0]._on_data, fleet.links[0]._on_datagrams
        message_inputs = MessageInputs()
        feed, feed_imu = message_inputs.feed, message_inputs.feed_imu
        n = 0
        for start in range(0, len(datagrams), wake_every):
            wakeup = datagrams[start : start + wake_every]
            if per_datagram:
                for datagram in wakeup:
                    on_data(datagram)
            else:
                on_datagrams(wakeup)
            fed: list[EstimationInput | ImuRow] = []
            for item in estimation.drain():
                if inputs:
                    if item.imu is None or per_datagram or not feed_imu(item.imu, fed):
                        fed += feed(item.reading, tlog_wall_time(item.wall_time))
                else:
                    item.reading  # noqa: B018 (read, as the estimation does)
            if inputs:  # the batch's IMU table, as the pipeline builds it (`ImuBatch.of`)
                ImuBatch.of([x for x in fed if isinstance(x, ImuSample | tuple)])
            for item in vehicle_state.drain():
                item.msg  # noqa: B018 (read, as the vehicle state does)
            n += len(recorder.drain())
            replies.drain()
        return n

    return asyncio.run(run())


def to_inputs(datagrams: list[bytes]) -> int:
    return serve_receive_path(datagrams, inputs=True)


def per_datagram(datagrams: list[bytes]) -> int:
    return serve_receive_path(datagrams, per_datagram=True)


def to_inputs_per_datagram(datagrams: list[bytes]) -> int:
    return serve_receive_path(datagrams, inputs=True, per_datagram=True)


def best_rate(fn, parts: list[bytes], repeats: int = 3, clock=time.perf_counter) -> tuple[float, int]:
    """The best of `repeats` runs of fn(parts), in messages per second of `clock` (process_time:
    per CPU second of this process, which others' load on the machine does not change)."""
    best = 0.0
    count = 0
    for _ in range(repeats):
        t0 = clock()
        count = fn(parts)
        best = max(best, count / (clock() - t0))
    return best, count


def main() -> list[dict]:
    rows = []
    parts = chunks(sample_stream())
    datagrams = [p for _, p in packets(1000, 60.0)]
    for name, baseline, ours, data in (
        ("link decode+dispatch", bare_pymavlink, link_and_bus, parts),
        ("serve receive path (fleet link, the station's subscriptions)", bare_pymavlink, serve_receive_path, datagrams),
        ("serve receive path, per datagram", bare_pymavlink, per_datagram, datagrams),
        ("serve receive path to the estimation's inputs", bare_pymavlink, to_inputs, datagrams),
        ("to the estimation's inputs, the path before", bare_pymavlink, to_inputs_per_datagram, datagrams),
    ):
        base, n_base = best_rate(baseline, data, 3, time.process_time)
        rate, n_ours = best_rate(ours, data, 3, time.process_time)
        assert n_base == n_ours, (n_base, n_ours)
        rows.append(
            {
                "benchmark": name,
                "baseline": "bare pymavlink parse_buffer",
                "baseline_per_s": round(base),
                "ours_per_s": round(rate),
                "ratio": round(rate / base, 3),
                "ours_us_per_msg": round(1e6 / rate, 2),
                "unit": "messages per CPU s",
                "n": n_ours,
            }
        )
    return rows


if __name__ == "__main__":
    for row in main():
        print(row)
