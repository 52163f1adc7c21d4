"""Stress cases built from the shared BROAD trials, for `bench.broad` and the acceptance tests
(tests/test_heading_stress.py): the one place that builds them.

    python -m bench.stress [--estimators dcm,kf,ekf] [--every 6] [--trials 02,07]

* **magnet**: a body-fixed field of `offset` µT (a battery strap, a screw, a camera next to the
  compass) added in the sensor frame from `t_on` on, along MAGNET_AXIS;
* **bias step**: `rate` rad/s added to one gyro axis from `t_on` on;
* **floor magnet**: a magnet lying at a fixed place under the motion (a steel beam, a motor on the
  bench, BROAD's trial 30 made up from any trial): a dipole FLOOR_MAGNET_DEPTH below the trial's
  lowest position (under its median one), moment along world east, strong enough for FLOOR_MAGNET_UT on its axis at that
  distance; its field at the optical position, turned into the sensor frame by the optical
  attitude, is added for the whole trial. It varies as the sensor moves, so the disturbance comes and
  goes: what a place-fixed disturbance does that a body-fixed one does not;
* **shocks**: accelerometer spikes of 8 to 16 g, `width` s long, every `period` s between `t_on`
  and `t_off` (a hard touch-down, a tap), along the sensor axes in turn.

Scoring is BROAD's (bench.broad.broad_errors) on the movement samples after `t_on` (magnet, bias)
or from `t_off + settle` on (shocks: what is left once they are over). Everything runs in-process
through the estimator classes (`gcs estimate` gives the same numbers, more slowly).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

from bench.broad import DATA, broad_errors, load_trial, run_estimator, run_vqf
from gcs.core.samples import G0

#: Direction of the synthetic magnet's field in the sensor frame (a fixed, arbitrary unit vector
#: with a component on every axis).
MAGNET_AXIS = np.array([0.6, -0.48, 0.64]) / np.linalg.norm([0.6, -0.48, 0.64])
MAGNET_UT = (20.0, 50.0, 100.0)
BIAS_STEP = math.radians(1.0)  # rad/s on sensor x
SHOCK_G = (8.0, 12.0, 16.0)
FLOOR_MAGNET_DEPTH = 0.3  # m below the lowest position
FLOOR_MAGNET_UT = 40.0  # µT on the dipole's axis at FLOOR_MAGNET_DEPTH

Trial = dict[str, np.ndarray | float]


def mid(trial: Trial) -> float:
    """The trial's middle (s): where the stress cases switch on."""
    t = np.asarray(trial["t"])
    return float(t[-1]) / 2.0


def magnet(trial: Trial, offset: float, t_on: float) -> Trial:
    """A body-fixed field of `offset` µT along MAGNET_AXIS from t_on on (BROAD's field is in µT)."""
    out = dict(trial)
    on = np.asarray(trial["t"]) >= t_on
    mag = np.array(trial["imu_mag"])
    mag[on] += offset * MAGNET_AXIS
    out["imu_mag"] = mag
    return out


def bias_step(trial: Trial, rate: float, t_on: float, axis: int = 0) -> Trial:
    """`rate` rad/s added to gyro `axis` from t_on on."""
    out = dict(trial)
    gyr = np.array(trial["imu_gyr"])
    gyr[np.asarray(trial["t"]) >= t_on, axis] += rate
    out["imu_gyr"] = gyr
    return out


def _filled(x: np.ndarray) -> np.ndarray:
    """Rows with NaN (optical tracking lost) replaced by the nearest earlier, else later, good row."""
    good = np.flatnonzero(np.all(np.isfinite(x), axis=1))
    index = np.searchsorted(good, np.arange(len(x)), side="right") - 1
    return np.asarray(x[good[np.clip(index, 0, len(good) - 1)]])


def floor_magnet(trial: Trial, peak: float = FLOOR_MAGNET_UT, depth: float = FLOOR_MAGNET_DEPTH) -> Trial:
    """A place-fixed dipole `depth` m below the lowest position (see the module docstring)."""
    out = dict(trial)
    pos = _filled(np.asarray(trial["opt_pos"]))
    quat = _filled(np.asarray(trial["opt_quat"]))
    below = np.array([*np.median(pos[:, :2], axis=0), pos[:, 2].min() - depth])
    r = pos - below
    dist = np.linalg.norm(r, axis=1, keepdims=True)
    unit = r / dist
    moment = np.array([peak * depth**3 / 2.0, 0.0, 0.0])  # on-axis field of a dipole: 2m/r³ (µ0/4π in m)
    field_enu = (3.0 * unit * (unit @ moment)[:, None] - moment) / dist**3
    w, v = quat[:, :1], -quat[:, 1:]  # sensor → ENU conjugated: ENU → sensor
    t = 2.0 * np.cross(v, field_enu)
    out["imu_mag"] = np.asarray(trial["imu_mag"]) + field_enu + w * t + np.cross(v, t)
    return out


def shocks(trial: Trial, t_on: float, t_off: float, period: float = 3.0, width: float = 0.02) -> Trial:
    """Accelerometer spikes (SHOCK_G in turn, along sensor x, y, z in turn, alternating sign) of
    `width` s every `period` s in [t_on, t_off)."""
    out = dict(trial)
    t = np.asarray(trial["t"])
    acc = np.array(trial["imu_acc"])
    for k, start in enumerate(np.arange(t_on, t_off, period)):
        sel = (t >= start) & (t < start + max(width, float(t[1] - t[0])))
        acc[sel, k % 3] += (-1.0) ** k * SHOCK_G[k % len(SHOCK_G)] * G0
    out["imu_acc"] = acc
    return out


def score(trial: Trial, q_enu: np.ndarray, t_from: float = 0.0) -> dict[str, float]:
    """BROAD errors (deg) on the movement samples at or after t_from."""
    moving = np.asarray(trial["movement"]) & (np.asarray(trial["t"]) >= t_from)
    return broad_errors(q_enu, np.asarray(trial["opt_quat"]), moving)


#: name → (build the stressed trial, time from which it is scored), both from the trial.
CASES: dict[str, Callable[[Trial], tuple[Trial, float]]] = {
    "none (second half)": lambda tr: (tr, mid(tr)),
    **{
        f"magnet {int(ut)} uT": (lambda tr, ut=ut: (magnet(tr, ut, mid(tr)), mid(tr)))  # type: ignore[misc]
        for ut in MAGNET_UT
    },
    "bias step 1 deg/s": lambda tr: (bias_step(tr, BIAS_STEP, mid(tr)), mid(tr)),
    "shocks 8-16 g": lambda tr: (shocks(tr, mid(tr) - 20.0, mid(tr)), mid(tr) + 10.0),
    "floor magnet": lambda tr: (floor_magnet(tr), 0.0),
}


def trial_paths(data: str | Path = DATA, keep: str = "") -> list[Path]:
    parts = [k for k in keep.split(",") if k]
    return [p for p in sorted(Path(data).glob("*.hdf5")) if not parts or any(k in p.stem for k in parts)]


def stress_rows(path: Path, every: int, estimators: tuple[str, ...]) -> list[dict[str, float | str]]:
    """One row per (case, estimator incl. VQF) on one trial: heading and total RMS after the switch."""
    trial = load_trial(path, every)
    rows: list[dict[str, float | str]] = []
    for case, build in CASES.items():
        stressed, t_from = build(trial)
        runs = {"vqf": run_vqf(stressed)} | {n: run_estimator(n, stressed) for n in estimators}
        for name, q in runs.items():
            err = score(stressed, q, t_from)
            rows.append(
                {
                    "benchmark": "stress",
                    "case": case,
                    "trial": path.stem,
                    "rate_hz": round(float(trial["rate"]), 1),
                    "estimator": name,
                    **err,
                }
            )  # type: ignore[arg-type]
    return rows


def print_trials(rows: list[dict[str, float | str]], metric: str = "heading") -> None:
    for r in rows:
        print(f"  {r['rate_hz']} {r['case']:<22} {r['trial']:<36} {r['estimator']:<4} {metric} {float(r[metric]):6.2f}")


def case_metric(case: str) -> str:
    """The figure a case is scored by: heading for the magnets (and none), total for the rest."""
    return "heading" if case.startswith(("magnet", "none", "floor")) else "total"


def worst_ratios(rows: list[dict[str, float | str]]) -> dict[tuple[float, str, str], tuple[float, str]]:
    """(rate, case, estimator) → (the worst ratio to VQF's figure on the same trial, that trial):
    the issue's "no trial or stress case worse than 2× VQF"."""
    vqf = {
        (r["rate_hz"], r["case"], r["trial"]): float(r[case_metric(str(r["case"]))])
        for r in rows
        if r["estimator"] == "vqf"
    }
    out: dict[tuple[float, str, str], tuple[float, str]] = {}
    for r in rows:
        if r["estimator"] == "vqf":
            continue
        key = (float(r["rate_hz"]), str(r["case"]), str(r["estimator"]))
        ratio = float(r[case_metric(str(r["case"]))]) / vqf[(r["rate_hz"], r["case"], r["trial"])]
        if key not in out or ratio > out[key][0]:
            out[key] = (ratio, str(r["trial"])[:2])
    return out


def print_stress(rows: list[dict[str, float | str]]) -> None:
    """Heading RMS (total RMS for the bias step and shocks) per case: the mean and the worst trial,
    then each estimator's worst ratio to VQF on one trial."""
    print("\nStress cases on BROAD (deg, RMS after the switch; shocks: from 10 s after the last):")
    ratios = worst_ratios(rows)
    for rate in dict.fromkeys(r["rate_hz"] for r in rows):
        names = list(dict.fromkeys(str(r["estimator"]) for r in rows if r["rate_hz"] == rate))
        print(f"\n{rate} Hz, mean / worst of the trials")
        print(f"{'case':<28}" + "".join(f"{n:>14}" for n in names))
        for case in dict.fromkeys(r["case"] for r in rows):
            metric = case_metric(str(case))
            cells = []
            for n in names:
                v = [float(r[metric]) for r in rows if (r["case"], r["estimator"], r["rate_hz"]) == (case, n, rate)]
                cells.append(f"{np.mean(v):6.2f} /{max(v):6.2f}")
            print(f"{str(case) + ' ' + metric:<28}" + "".join(f"{c:>14}" for c in cells))
        print(f"\n{rate} Hz, worst ratio to VQF on one trial (trial)")
        print(f"{'case':<28}" + "".join(f"{n:>14}" for n in names if n != "vqf"))
        for case in dict.fromkeys(r["case"] for r in rows):
            cells = [
                f"{ratios[(float(rate), str(case), n)][0]:6.2f} ({ratios[(float(rate), str(case), n)][1]})"
                for n in names
                if n != "vqf"
            ]
            print(f"{str(case):<28}" + "".join(f"{c:>14}" for c in cells))


def main(argv: list[str] | None = None) -> list[dict[str, float | str]]:
    parser = argparse.ArgumentParser(prog="bench.stress", description=__doc__.splitlines()[0])
    parser.add_argument("--estimators", default="dcm,kf,ekf")
    parser.add_argument("--data", default=str(DATA))
    parser.add_argument("--trials", default="")
    parser.add_argument("--every", default="6", help="decimations, e.g. 1,6")
    parser.add_argument("--verbose", action="store_true", help="every trial's figure too")
    parser.add_argument("--json", help="write every row as JSON to this file")
    args = parser.parse_args(argv if argv is not None else [])
    estimators = tuple(n for n in args.estimators.split(",") if n)
    rows = [
        row
        for every in (int(k) for k in args.every.split(","))
        for path in trial_paths(args.data, args.trials)
        for row in stress_rows(path, every, estimators)
    ]
    if args.verbose:
        print_trials(rows)
    print_stress(rows)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=2)
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
