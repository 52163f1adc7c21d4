"""BROAD benchmark: our estimators through `gcs estimate` against optical ground truth, with VQF
beside them as the reference.

    python -m bench.broad [--json FILE] [--estimators dcm,kf,ekf] [--data DIR]

Each trial in ../shared/data/broad is written to a temporary CSV (t,gx,...,mz in BROAD's own
right-handed sensor frame, which is z-up) and run through the CLI as a subprocess, once at the full
285.7 Hz and once keeping every 6th sample (47.6 Hz, what RAW_IMU streaming gives; picking, no
anti-alias filter). VQF (`vqf.VQF`, the causal real-time filter with its default parameters, 9D)
runs on the same samples in-process.

Metric, exactly as data/README.md and the BROAD paper's example code: both attitudes sensor → ENU,
q_e = q_est ⊗ q_opt⁻¹, total = 2·acos|w|, heading = 2·atan|z/w|, inclination = 2·acos√(w²+z²),
RMS over the samples where `movement` is true, NaN (no optical tracking) skipped.

Leave-one-trial-out tuning: bench.loo.

Heading reference: BROAD's ENU is magnetic north; our estimators run with declination 0, so they
output magnetic-north NED, turned into ENU by q_ENU = q(NED→ENU) ⊗ q_est with q(NED→ENU) =
(0, 1/√2, 1/√2, 0). No heading offset or any other alignment is fitted or removed — not for VQF
and not for ours — which is the BROAD paper's convention.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from gcs.core.estimators import registry
from gcs.core.rotation import quat_conjugate, quat_multiply
from gcs.core.samples import ImuSample

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "broad"
ESTIMATORS = ("dcm", "kf", "ekf")
DECIMATIONS = (1, 6)  # full rate, and every 6th sample (47.6 Hz)
Q_NED_TO_ENU = np.array([0.0, math.sqrt(0.5), math.sqrt(0.5), 0.0])


def broad_errors(q_est_enu: np.ndarray, q_opt: np.ndarray, movement: np.ndarray) -> dict[str, float]:
    """RMS total / heading / inclination error in degrees (BROAD's metric, see module docstring)."""
    q_est = q_est_enu / np.linalg.norm(q_est_enu, axis=1, keepdims=True)
    q_ref = q_opt / np.linalg.norm(q_opt, axis=1, keepdims=True)
    w, _, _, z = quat_multiply(q_est.T, quat_conjugate(q_ref.T))  # elementwise: (4, N) → N products
    with np.errstate(invalid="ignore", divide="ignore"):
        angles = {
            "total": 2 * np.arccos(np.clip(np.abs(w), 0.0, 1.0)),
            "heading": 2 * np.arctan(np.abs(z / w)),
            "inclination": 2 * np.arccos(np.clip(np.sqrt(w * w + z * z), 0.0, 1.0)),
        }
    out = {}
    for name, a in angles.items():
        a = a[movement & np.isfinite(a)]
        out[name] = float(np.degrees(np.sqrt(np.mean(a * a))))
    return out


def load_trial(path: Path, every: int) -> dict[str, np.ndarray | float]:
    import h5py

    with h5py.File(path, "r") as f:
        rate = float(f.attrs["sampling_rate"])
        keys = ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "opt_pos")
        trial = {k: np.ascontiguousarray(f[k][::every], dtype=float) for k in keys}
        trial["movement"] = np.asarray(f["movement"][::every], dtype=bool)
    trial["t"] = np.arange(len(trial["imu_gyr"])) * (every / rate)
    trial["rate"] = rate / every
    return trial


def write_csv(path: str, trial: dict) -> None:
    data = np.column_stack([trial["t"], trial["imu_gyr"], trial["imu_acc"], trial["imu_mag"]])
    np.savetxt(path, data, fmt="%.9g", delimiter=",", header="t,gx,gy,gz,ax,ay,az,mx,my,mz", comments="")


def run_cli(estimator: str, csv_path: str, out_path: str) -> tuple[np.ndarray, float]:
    """Quaternions (sensor → NED) from `gcs estimate`, and the wall time of the run."""
    cmd = [sys.executable, "-m", "gcs", "estimate", csv_path, "--estimator", estimator, "--out", out_path]
    start = time.perf_counter()
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    elapsed = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({done.returncode}): {done.stderr.strip()}")
    return np.loadtxt(out_path, delimiter=",", skiprows=1, usecols=(1, 2, 3, 4), ndmin=2), elapsed


def run_vqf(trial: dict) -> np.ndarray:
    """VQF 9D (sensor → ENU, magnetic north), default parameters."""
    from vqf import VQF

    return VQF(1.0 / trial["rate"]).updateBatch(trial["imu_gyr"], trial["imu_acc"], trial["imu_mag"])["quat9D"]


def run_estimator(name: str, trial: dict, **gains: float) -> np.ndarray:
    """Estimator `name` (default preset, gain overrides) in-process over the trial: N×4 quaternions
    sensor → ENU, the numbers `gcs estimate` gives."""
    est = registry.create(name, **gains)
    t, gyr, acc, mag = (np.asarray(trial[k]) for k in ("t", "imu_gyr", "imu_acc", "imu_mag"))
    q = np.empty((len(t), 4))
    for k in range(len(t)):
        est.update_imu(ImuSample(float(t[k]), gyr[k], acc[k], mag[k]))
        q[k] = est.quaternion
    return np.asarray(quat_multiply(Q_NED_TO_ENU, q.T).T)


def bench_trial(path: Path, every: int, estimators: tuple[str, ...], tmp: str) -> list[dict]:
    trial = load_trial(path, every)
    csv_path = os.path.join(tmp, f"{path.stem}_{every}.csv")
    write_csv(csv_path, trial)
    n = len(trial["t"])
    base = {"benchmark": "broad", "rate_hz": round(trial["rate"], 1), "trial": path.stem}
    start = time.perf_counter()
    rows = [
        {
            **base,
            "estimator": "vqf",
            **broad_errors(run_vqf(trial), trial["opt_quat"], trial["movement"]),
            "us_per_sample": 1e6 * (time.perf_counter() - start) / n,
        }
    ]
    for name in estimators:
        q_ned, elapsed = run_cli(name, csv_path, os.path.join(tmp, f"{path.stem}_{every}_{name}.out.csv"))
        if len(q_ned) != n:
            raise RuntimeError(f"{name} on {path.stem}: {len(q_ned)} output rows for {n} samples")
        q_enu = quat_multiply(Q_NED_TO_ENU, q_ned.T).T
        rows.append(
            {
                **base,
                "estimator": name,
                **broad_errors(q_enu, trial["opt_quat"], trial["movement"]),
                "us_per_sample": 1e6 * elapsed / n,
            }
        )
    os.remove(csv_path)
    return rows


def mean_rows(rows: list[dict]) -> list[dict]:
    out = []
    for key in dict.fromkeys((r["rate_hz"], r["estimator"]) for r in rows):
        sel = [r for r in rows if (r["rate_hz"], r["estimator"]) == key]
        mean = {k: float(np.mean([r[k] for r in sel])) for k in ("total", "heading", "inclination", "us_per_sample")}
        name = f"mean of {len(sel)}"
        out.append({"benchmark": "broad", "rate_hz": key[0], "trial": name, "estimator": key[1], **mean})
    return out


def print_table(rows: list[dict]) -> None:
    trials = list(dict.fromkeys(r["trial"] for r in rows if not r["trial"].startswith("mean")))
    print("BROAD: RMS error in degrees over movement samples; total per trial, then the means.")
    print("Heading: magnetic-north ENU truth vs magnetic-north output (declination 0); no alignment fitted")
    print("or removed, for VQF and ours alike (the BROAD paper's convention).")
    for rate in dict.fromkeys(r["rate_hz"] for r in rows):
        print(f"\n{rate} Hz")
        names = list(dict.fromkeys(r["estimator"] for r in rows if r["rate_hz"] == rate))
        print(f"{'trial':<36}" + "".join(f"{n:>9}" for n in names))
        for trial in trials:
            cells = {r["estimator"]: r["total"] for r in rows if r["rate_hz"] == rate and r["trial"] == trial}
            print(f"{trial:<36}" + "".join(f"{cells[n]:9.2f}" for n in names))
        for metric in ("total", "heading", "inclination", "us_per_sample"):
            cells = {r["estimator"]: r[metric] for r in rows if r["rate_hz"] == rate and r["trial"].startswith("mean")}
            print(f"{'mean ' + metric:<36}" + "".join(f"{cells[n]:9.2f}" for n in names))


def main(argv: list[str] | None = None) -> list[dict]:
    """Run the benchmark; returns one row per (rate, estimator, trial) plus the mean rows."""
    parser = argparse.ArgumentParser(prog="bench.broad", description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="write every row as JSON to this file")
    parser.add_argument("--estimators", default=",".join(ESTIMATORS), help="comma-separated `gcs estimate` names")
    parser.add_argument("--data", default=str(DATA), help="directory of BROAD *.hdf5 trials")
    parser.add_argument("--trials", default="", help="comma-separated parts of trial names to keep (default all)")
    parser.add_argument("--every", default=",".join(map(str, DECIMATIONS)), help="decimations to run, e.g. 1,6")
    args = parser.parse_args(argv if argv is not None else [])
    keep = [k for k in args.trials.split(",") if k]
    paths = [p for p in sorted(Path(args.data).glob("*.hdf5")) if not keep or any(k in p.stem for k in keep)]
    if not paths:
        raise SystemExit(f"bench.broad: no *.hdf5 trials in {args.data}")
    estimators = tuple(n for n in args.estimators.split(",") if n)
    with tempfile.TemporaryDirectory(prefix="broad-") as tmp, ThreadPoolExecutor(os.cpu_count() or 1) as pool:
        decimations = [int(k) for k in args.every.split(",")]
        jobs = [pool.submit(bench_trial, p, every, estimators, tmp) for every in decimations for p in paths]
        rows = [row for job in jobs for row in job.result()]
    rows += mean_rows(rows)
    print_table(rows)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=2)
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
