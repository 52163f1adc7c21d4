"""µs of CPU per message of the live estimation (`LiveEstimation._feed`: messages → samples →
three estimators → comparisons), against the bare kernels on the same IMU samples, in one run.

Stream: bench.serve_cpu's PX4-like mix (HIGHRES_IMU 400 : ATTITUDE 100 : GPS_RAW_INT 5 :
HEARTBEAT 1; the estimation subscribes to all but HEARTBEAT), SECONDS of it, decoded once up
front and fed in batches of `gcs.runtime.estimation.BATCH` as the live loop drains them when
behind, and of `TURN` as `gcs serve` drains them on this stream (its estimation tick brought 6.7
messages per turn on average, docs/benchmarks.md): a batch's fixed costs weigh more there.
Baseline: the registered (compiled) estimators' `update_imu(sample)` + `.quaternion` on the
IMU samples those messages give, nothing else. CPU time (`time.process_time`), best of REPEATS.
`python_us` = pipeline − kernels per message: the Python around the kernels (issue 17).
"""

from __future__ import annotations

import time

from bench.serve_cpu import packets
from gcs.core.estimation import EstimationPipeline
from gcs.core.estimators import registry
from gcs.core.samples import ImuSample
from gcs.mavlink.dialect import mavlink
from gcs.mavlink.sampling import INPUT_TYPES, MessageInputs
from gcs.runtime.bus import Message
from gcs.runtime.estimation import BATCH, LiveEstimation

SECONDS = 20.0
REPEATS = 3
TURN = 7


def messages() -> list[Message]:
    parser = mavlink.MAVLink(None)
    out = []
    for k, (t, raw) in enumerate(packets(1000, SECONDS)):
        msg = parser.parse_char(raw)
        if msg is not None and msg.get_type() in INPUT_TYPES:
            out.append(Message.of(msg, t, 1.8e9 + t + k * 1e-7))
    return out


def pipeline_us(items: list[Message], batch: int = BATCH) -> float:
    best = float("inf")
    for _ in range(REPEATS):
        live = LiveEstimation(link=None, pipeline=EstimationPipeline())  # type: ignore[arg-type]
        started = time.process_time()
        for i in range(0, len(items), batch):
            live._feed(items[i : i + batch])
        best = min(best, time.process_time() - started)
    return 1e6 * best / len(items)


def kernels_us(items: list[Message]) -> float:
    sampler = MessageInputs().sampler
    imu = [s for m in items for s in sampler.feed(m.msg) if isinstance(s, ImuSample)]
    best = float("inf")
    for _ in range(REPEATS):
        estimators = [registry.create(n) for n in registry.names()]
        started = time.process_time()
        for s in imu:
            for est in estimators:
                est.update_imu(s)
                est.quaternion  # noqa: B018 - read as the pipeline does
        best = min(best, time.process_time() - started)
    return 1e6 * best / len(items)


def main() -> list[dict]:
    registry.warm()
    items = messages()
    base = kernels_us(items)
    rows = []
    for batch in (BATCH, TURN):
        ours = pipeline_us(items, batch)
        rows.append(
            {
                "benchmark": f"live pipeline µs/message (PX4-like mix, 3 estimators), {batch} messages per turn",
                "baseline": "the 3 compiled kernels alone on its IMU samples",
                "baseline_us": round(base, 2),
                "ours_us": round(ours, 2),
                "python_us": round(ours - base, 2),
                "ratio": round(ours / base, 2),
                "n": len(items),
            }
        )
    return rows


if __name__ == "__main__":
    for row in main():
        print(row)
