"""CPU of the /ws/live frames, encoding on the server's loop and decoding in a reader, per frame of
the live hub's usual size (10 ms of six sources at 400 Hz: 4 samples each).
`python -m bench.wire`

Baseline, in the same run: the JSON frames the binary ones replaced (each number rounded, then
`strict_json.dumps`, `{"type":"points","seq":..,"server_time":..,"points":{source: [[t],[roll],
[pitch],[yaw]]}}`), and `json.loads` for reading them.
"""

from __future__ import annotations

import json
import random
import sys
import time

from gcs.core import strict_json
from gcs.server import wire

SOURCES = ("onboard", "ahrs2", "truth", "dcm", "kf", "ekf")
SAMPLES = 4  # per source in a 10 ms frame at 400 Hz
FRAMES = 20_000


def frame_columns(rng: random.Random, t0: float) -> dict[str, list[list[float]]]:
    return {
        s: [[t0 + k / 400 for k in range(SAMPLES)], *([rng.uniform(-180, 180) for _ in range(SAMPLES)] for _ in "rpy")]
        for s in SOURCES
    }


def json_frame(seq: int, server_time: float, points: dict[str, list[list[float]]]) -> str:
    rounded = {s: [[round(t, 6) for t in c[0]], *([round(v, 3) for v in a] for a in c[1:])] for s, c in points.items()}
    return strict_json.dumps(
        {"type": "points", "seq": seq, "server_time": server_time, "points": rounded}, separators=(",", ":")
    )


def cpu_us(work, items: list) -> float:
    started = time.process_time()
    for item in items:
        work(item)
    return 1e6 * (time.process_time() - started) / len(items)


def main(argv: list[str] | None = None) -> list[dict]:
    del argv
    rng = random.Random(1)
    frames = [frame_columns(rng, k / 100) for k in range(FRAMES)]
    encoded_json = [json_frame(k, 0.0, f) for k, f in enumerate(frames)]
    encoded_binary = [wire.points_frame(k, 0.0, f) for k, f in enumerate(frames)]
    rows = []
    for what, ours, baseline in (
        (
            "encode",
            cpu_us(lambda f: wire.points_frame(1, 0.0, f), frames),
            cpu_us(lambda f: json_frame(1, 0.0, f), frames),
        ),
        ("decode", cpu_us(lambda b: list(wire.decode(b)), encoded_binary), cpu_us(json.loads, encoded_json)),
    ):
        rows.append(
            {
                "benchmark": f"/ws/live frame {what}, {len(SOURCES)} sources x {SAMPLES} samples",
                "value_us": round(ours, 1),
                "baseline": f"JSON {baseline:.1f} us",
                "ratio": round(ours / baseline, 2),
            }
        )
    size_binary = sum(map(len, encoded_binary)) / FRAMES
    size_json = sum(len(s.encode()) for s in encoded_json) / FRAMES
    rows.append(
        {
            "benchmark": "/ws/live frame size",
            "value_bytes": round(size_binary),
            "baseline": f"JSON {size_json:.0f} bytes",
            "ratio": round(size_binary / size_json, 2),
        }
    )
    return rows


if __name__ == "__main__":
    for row in main(sys.argv[1:]):
        print(row)
