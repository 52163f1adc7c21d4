"""What routing by vehicle costs the receive path: messages/s through a fleet's link (the
vehicle's own view: counters, heartbeat state, its own bus) as a ratio to a one-vehicle
station's link (`Link` publishing straight to the bus the station's parts read), over the same
bytes in the same run.

Baseline `station link`: `Link._on_data` + publish to one subscriber (bench.link_throughput's
path). Ours: the same through `Fleet`'s link bus to the vehicle's `VehicleLink` and one
subscriber of its bus; once with one vehicle, once with two interleaved (sysid 1 and 2).
"""

from __future__ import annotations

import asyncio
import time

from bench.link_throughput import best_rate
from gcs.mavlink.dialect import Encoder, mavlink
from gcs.runtime.fleet import Fleet
from gcs.runtime.link import Link
from gcs.runtime.station import StationConfig

CHUNK = 4096
#: what the consumers ask for by name: every type of the stream, so the link decodes each one
TYPES = ("HEARTBEAT", "RAW_IMU", "ATTITUDE", "GPS_RAW_INT", "SCALED_PRESSURE")


def sample_stream(sysids: tuple[int, ...], n: int = 60_000) -> bytes:
    encoders = [Encoder(sysid, 1) for sysid in sysids]
    cycle = [
        lambda k: mavlink.MAVLink_heartbeat_message(2, 3, 81, 0, 4, 3),
        lambda k: mavlink.MAVLink_raw_imu_message(k * 5000, 10, -20, -1000, 1, 2, 3, 200, -50, 400),
        lambda k: mavlink.MAVLink_attitude_message(k * 5, 0.1, -0.2, 3.0, 0.01, 0.02, 0.03),
        lambda k: mavlink.MAVLink_gps_raw_int_message(k, 3, 71234567, -1234567, 1500, 100, 100, 250, 9000, 12),
        lambda k: mavlink.MAVLink_scaled_pressure_message(k * 5, 1013.0, 0.1, 2000),
    ]
    return b"".join(encoders[k % len(encoders)].encode(cycle[(k // len(encoders)) % len(cycle)](k)) for k in range(n))


def chunks(data: bytes) -> list[bytes]:
    return [data[i : i + CHUNK] for i in range(0, len(data), CHUNK)]


def station_link(parts: list[bytes]) -> int:
    async def run() -> int:
        link = Link("tcp:127.0.0.1:9")
        sub = link.bus.subscribe("consumer", types=TYPES, maxlen=100_000)
        delivered = 0
        for part in parts:
            link._on_data(part)
            delivered += len(sub.drain())
        return delivered

    return asyncio.run(run())


def fleet_link(parts: list[bytes]) -> int:
    async def run() -> int:
        fleet = Fleet(StationConfig(connect="tcp:127.0.0.1:9"))
        subs = [fleet.first.bus.subscribe("consumer", types=TYPES, maxlen=100_000)]
        fleet.vehicle_added.connect(
            lambda e: (
                e.station is fleet.first
                or subs.append(e.station.bus.subscribe("consumer", types=TYPES, maxlen=100_000))
            )
        )
        delivered = 0
        for part in parts:
            fleet.links[0]._on_data(part)
            delivered += sum(len(sub.drain()) for sub in subs)
        return delivered

    return asyncio.run(run())


def main() -> list[dict]:
    rows = []
    for sysids in ((1,), (1, 2)):
        parts = chunks(sample_stream(sysids))
        base, n_base = best_rate(station_link, parts, 5, time.process_time)
        ours, n_ours = best_rate(fleet_link, parts, 5, time.process_time)
        assert n_base == n_ours, (n_base, n_ours)  # every message reaches its vehicle
        rows.append(
            {
                "benchmark": f"fleet routing, {len(sysids)} vehicle{'s' if len(sysids) > 1 else ''} on the link",
                "baseline": "one-vehicle station link",
                "baseline_per_s": round(base),
                "ours_per_s": round(ours),
                "ratio": round(ours / base, 3),
                "unit": "messages/s",
                "n": n_ours,
                "n_baseline": n_base,
            }
        )
    return rows


if __name__ == "__main__":
    for row in main():
        print(row)
