"""µs of CPU per IMU sample of each estimator, compiled and readable reference, against VQF.

The same 20 s of a real BROAD trial (24, tapping: shocks and motion; 285.7 Hz, 9D) fed one
sample at a time from Python, as the live pipeline and replay feed them: `update_imu(sample)`
then `.quaternion`. Baseline: VQF (`vqf.VQF`, its C++ core behind a Cython call) in the same
loop, `update(gyr, acc, mag)` then `getQuat9D()`. CPU time (`time.process_time`), the best of
REPEATS, so other processes on a shared machine weigh less. Ratio = VQF / ours (> 1: faster).
Target: compiled ≤ 5 µs per sample. Beside it (`whole_us`) the same samples through the whole-run
loop (gcs.core.estimators.whole, what-if and `replay --fast`): the kernels without the
per-sample call from Python.
"""

from __future__ import annotations

import time
from pathlib import Path

import h5py
import numpy as np

from gcs.core.estimators import registry
from gcs.core.estimators.dcm import DcmEstimator
from gcs.core.estimators.ekf import EkfEstimator
from gcs.core.estimators.kf import KalmanAttitudeFilter
from gcs.core.estimators.whole import run_whole
from gcs.core.samples import ImuSample
from gcs.logs.input_table import InputTableBuilder

TRIAL = next((Path(__file__).resolve().parents[2] / "shared" / "data" / "broad").glob("24_*.hdf5"))
REFERENCES = {"dcm": DcmEstimator, "kf": KalmanAttitudeFilter, "ekf": EkfEstimator}
SECONDS = 20.0
REPEATS = 3


def samples() -> list[ImuSample]:
    with h5py.File(TRIAL, "r") as f:
        rate = float(f.attrs["sampling_rate"])
        n = int(SECONDS * rate)
        gyr, acc, mag = (np.asarray(f[k][:n], dtype=float) for k in ("imu_gyr", "imu_acc", "imu_mag"))
    return [ImuSample(k / rate, gyr[k], acc[k], mag[k]) for k in range(n)]


def us_per_sample(make, data: list[ImuSample], repeats: int = REPEATS) -> float:
    best = float("inf")
    for _ in range(repeats):
        est = make()
        started = time.process_time()
        for s in data:
            est.update_imu(s)
            est.quaternion  # noqa: B018 - read as the pipeline does
        best = min(best, time.process_time() - started)
    return 1e6 * best / len(data)


def whole_us_per_sample(name: str, data: list[ImuSample], repeats: int = REPEATS) -> float:
    builder = InputTableBuilder()
    for s in data:
        builder.append(s)
    table = builder.build()
    best = float("inf")
    for _ in range(repeats):
        est = registry.create(name)
        started = time.process_time()
        run_whole(est, table.kind, table.imu, table.gps, table.gain_change, name)
        best = min(best, time.process_time() - started)
    return 1e6 * best / len(data)


def vqf_us_per_sample(data: list[ImuSample], repeats: int = REPEATS) -> float:
    from vqf import VQF

    dt = data[1].t - data[0].t
    best = float("inf")
    for _ in range(repeats):
        v = VQF(dt)
        started = time.process_time()
        for s in data:
            v.update(s.gyro, s.accel, s.mag)
            v.getQuat9D()
        best = min(best, time.process_time() - started)
    return 1e6 * best / len(data)


def main() -> list[dict]:
    data = samples()
    registry.warm()
    base = vqf_us_per_sample(data)
    rows = []
    for name, reference in REFERENCES.items():
        compiled = us_per_sample(lambda n=name: registry.create(n), data)
        readable = us_per_sample(reference, data[: len(data) // 4], repeats=1)
        whole_us_per_sample(name, data[:10], repeats=1)  # the whole-run loop loaded
        rows.append(
            {
                "benchmark": f"{name} µs/sample (BROAD 24, 285.7 Hz, 9D)",
                "baseline": "VQF (C++ core) in the same loop",
                "baseline_us": round(base, 2),
                "ours_us": round(compiled, 2),
                "whole_us": round(whole_us_per_sample(name, data), 2),
                "reference_us": round(readable, 1),
                "ratio": round(base / compiled, 2),
                "speedup_vs_reference": round(readable / compiled, 1),
                "target": "≤ 5 µs",
                "met": compiled <= 5.0,
                "n": len(data),
            }
        )
    return rows


if __name__ == "__main__":
    for row in main():
        print(row)
