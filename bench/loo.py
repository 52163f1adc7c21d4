"""Leave-one-trial-out tuning on BROAD: how good the figures are on a trial the gains never saw.

    python -m bench.loo [--estimators dcm,kf,ekf] [--every 6] [--jobs 2] [--floor-magnet] [--json FILE]

For each estimator and rate, TUNED's 2-3 gains are searched on five trials (coordinate search over
the default × FACTORS, SWEEPS passes) and scored on the sixth, beside the defaults and the same
search on all six (in-sample). Every gain set is run once on every case and cached, so the six
folds share their runs (both rates of one estimator: 4 min for dcm, 9 min for kf on two loaded cores).

The search's cost is the mean plus the worst total RMSE over the training cases: each training
trial as recorded and, with --floor-magnet, also the same trial with bench.stress's floor magnet
(a place-fixed disturbance made from that trial alone, an attempt to let the training constrain
the heading loop's time constant; it did not help: docs/benchmarks.md). The held-out trial is
scored as recorded.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
from concurrent.futures import Executor, ProcessPoolExecutor
from pathlib import Path

import numpy as np

from bench.broad import DATA, broad_errors, load_trial, run_estimator, run_vqf
from bench.stress import floor_magnet, trial_paths
from gcs.core.estimators import registry

#: The 2-3 gains tuned per estimator (those BROAD is most sensitive to).
TUNED = {
    "dcm": ("kp_rp", "kp_yaw", "accel_tau"),
    "kf": ("k_q", "r_yaw", "accel_tau"),
    "ekf": ("gyro_noise", "acc_noise", "mag_noise"),
}
FACTORS = (0.25, 0.5, 1.0, 2.0, 4.0)
SWEEPS = 2
#: How a training case is made from a trial: as recorded, or with the floor magnet.
VARIANTS = {"recorded": lambda trial: trial, "floor magnet": floor_magnet}

Case = tuple[str, str]  # (trial stem, variant)


@functools.lru_cache(maxsize=12)
def _trial(path: str, every: int, variant: str) -> dict:
    return VARIANTS[variant](load_trial(Path(path), every))


def _total(name: str, path: str, every: int, variant: str, gains: tuple[tuple[str, float], ...]) -> float:
    trial = _trial(path, every, variant)
    return broad_errors(run_estimator(name, trial, **dict(gains)), trial["opt_quat"], trial["movement"])["total"]


class Tuner:
    """Total RMSE of one estimator at one rate on every case for any gain set, computed once each."""

    def __init__(self, name: str, paths: list[Path], every: int, variants: tuple[str, ...], pool: Executor) -> None:
        self.name, self.every, self.pool = name, every, pool
        self.paths = {p.stem: p for p in paths}
        self.cases: list[Case] = [(p.stem, v) for p in paths for v in variants]
        self.cache: dict[tuple[tuple[str, float], ...], dict[Case, float]] = {}
        declared = registry.get(name)().gains.declarations
        self.grid = {
            g: sorted({min(max(declared[g].default * f, declared[g].min), declared[g].max) for f in FACTORS})
            for g in TUNED[name]
        }
        self.default = {g: declared[g].default for g in TUNED[name]}

    def scores(self, gains: dict[str, float]) -> dict[Case, float]:
        key = tuple(sorted(gains.items()))
        if key not in self.cache:
            jobs = {
                case: self.pool.submit(_total, self.name, str(self.paths[case[0]]), self.every, case[1], key)
                for case in self.cases
            }
            self.cache[key] = {case: job.result() for case, job in jobs.items()}
        return self.cache[key]

    def score(self, gains: dict[str, float], stem: str) -> float:
        return self.scores(gains)[(stem, "recorded")]

    def search(self, train: list[str]) -> dict[str, float]:
        """Coordinate search from the defaults over the training trials' cases."""

        def cost(gains: dict[str, float]) -> float:
            v = [s for (stem, _), s in self.scores(gains).items() if stem in train]
            return float(np.mean(v) + np.max(v))

        best = dict(self.default)
        for _ in range(SWEEPS):
            before = dict(best)
            for gain, values in self.grid.items():
                best = min(({**best, gain: v} for v in values), key=cost)
            if best == before:
                break
        return best


def leave_one_out(
    paths: list[Path], estimators: tuple[str, ...], decimations: list[int], variants: tuple[str, ...], jobs: int
) -> list[dict]:
    """Rows per (estimator, rate, held-out trial): default, tuned on all six (in-sample), tuned on
    the other five (out-of-sample) total RMSE, VQF's, and the gains each chose."""
    rows = []
    with ProcessPoolExecutor(jobs) as pool:
        for every in decimations:
            vqf = {}
            for p in paths:
                trial = load_trial(p, every)
                vqf[p.stem] = broad_errors(run_vqf(trial), trial["opt_quat"], trial["movement"])["total"]
            for name in estimators:
                tuner = Tuner(name, paths, every, variants, pool)
                stems = [p.stem for p in paths]
                on_all = tuner.search(stems)
                for held in stems:
                    loo = tuner.search([s for s in stems if s != held])
                    rows.append(
                        {
                            "benchmark": "broad_loo",
                            "rate_hz": round(285.714 / every, 1),
                            "estimator": name,
                            "trial": held,
                            "training": list(variants),
                            "default": tuner.score(tuner.default, held),
                            "tuned_all": tuner.score(on_all, held),
                            "loo": tuner.score(loo, held),
                            "vqf": vqf[held],
                            "gains_all": on_all,
                            "gains_loo": loo,
                        }
                    )
                print(f"leave-one-out: {name} every {every}: {len(tuner.cache)} gain sets tried", file=sys.stderr)
    return rows


def print_loo(rows: list[dict], variants: tuple[str, ...]) -> None:
    print("\nLeave-one-trial-out (total RMSE, deg): tuned on five trials, scored on the sixth; 'all' is")
    print(f"tuned and scored on all six (in-sample). Search: {', '.join(f'{k} {v}' for k, v in TUNED.items())};")
    print(f"grid = default x {FACTORS}, {SWEEPS} coordinate passes, cost = mean + max over the training")
    print(f"trials, each {' and '.join(variants)}.")
    print(f"{'rate':>6} {'estimator':<9}" + "".join(f"{c:>16}" for c in ("default", "tuned all", "LOO", "VQF")))
    for key in dict.fromkeys((r["rate_hz"], r["estimator"]) for r in rows):
        sel = [r for r in rows if (r["rate_hz"], r["estimator"]) == key]
        cells = [
            f"{np.mean([r[c] for r in sel]):6.2f} /{max(r[c] for r in sel):6.2f}"
            for c in ("default", "tuned_all", "loo", "vqf")
        ]
        print(f"{key[0]:>6} {key[1]:<9}" + "".join(f"{c:>16}" for c in cells))
    print("(mean / worst of the six held-out trials)")
    for r in rows:
        print(
            f"  {r['rate_hz']:>6} {r['estimator']:<4} {r['trial']:<36} LOO {r['loo']:5.2f}"
            f" VQF {r['vqf']:5.2f}  gains {r['gains_loo']}"
        )


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(prog="bench.loo", description=__doc__.splitlines()[0])
    parser.add_argument("--estimators", default="dcm,kf,ekf")
    parser.add_argument("--data", default=str(DATA))
    parser.add_argument("--every", default="6", help="decimations, e.g. 1,6")
    parser.add_argument("--jobs", type=int, default=2, help="processes for the runs")
    parser.add_argument("--floor-magnet", action="store_true", help="train on floor-magnet copies as well")
    parser.add_argument("--json", help="write every row as JSON to this file")
    args = parser.parse_args(argv if argv is not None else [])
    variants = tuple(VARIANTS) if args.floor_magnet else ("recorded",)
    estimators = tuple(n for n in args.estimators.split(",") if n)
    decimations = [int(k) for k in args.every.split(",")]
    rows = leave_one_out(trial_paths(args.data), estimators, decimations, variants, args.jobs)
    print_loo(rows, variants)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=2)
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
