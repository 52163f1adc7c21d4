"""Messages/s decoded and dispatched by the link + bus, as a ratio to a bare pymavlink parse
loop over the same bytes in the same run.

Baseline `pymavlink`: `MAVLink.parse_buffer` on 4 KiB chunks plus `get_type()` per message
(the loop every pymavlink tool runs). Ours: `Link._on_data` on the same chunks: the
resynchronising decoder, per-type counters, the stamped `Message` and a bus publish to one
subscriber, which is exactly the live receive path of every transport.
"""

from __future__ import annotations

import asyncio
import time

from gcs.mavlink.dialect import Encoder, MAVLink, mavlink
from gcs.runtime.link import Link

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
        sub = link.bus.subscribe("consumer", maxlen=100_000)
        for part in parts:
            link._on_data(part)
            sub.drain()
        return link.stats.framing.packets

    return asyncio.run(run())


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
    parts = chunks(sample_stream())
    base, n_base = best_rate(bare_pymavlink, parts)
    ours, n_ours = best_rate(link_and_bus, parts)
    assert n_base == n_ours, (n_base, n_ours)
    return [
        {
            "benchmark": "link decode+dispatch",
            "baseline": "bare pymavlink parse_buffer",
            "baseline_per_s": round(base),
            "ours_per_s": round(ours),
            "ratio": round(ours / base, 3),
            "unit": "messages/s",
            "n": n_ours,
        },
    ]


if __name__ == "__main__":
    for row in main():
        print(row)
