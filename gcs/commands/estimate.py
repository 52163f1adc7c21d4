"""`gcs estimate`: run one attitude estimator over a log or CSV and write its attitude as CSV.

Contract (other tools call this; keep it stable):
    gcs estimate INPUT --estimator NAME [--preset P] [--gain NAME=VALUE ...] [--imu N] --out OUT.csv
    gcs estimate INPUT --preset-file FILE.toml [--gain NAME=VALUE ...] --out OUT.csv
    gcs estimate --list
INPUT is a .tlog, a DataFlash .bin or text .log, a ULog .ulg or a CSV (see gcs.logs.readers); --imu picks the
IMU instance (default 0, the first). OUT has the header t,qw,qx,qy,qz,roll,pitch,yaw and one row
per IMU sample; q rotates sensor/body → NED and the angles are Z-Y-X in degrees. Before the
filter is valid the row holds its current (initial) attitude. Bad input or arguments: one line on
stderr naming what and where, exit code 2, and no OUT (OUT is written beside itself and renamed
when complete, so a failed run never leaves a partial file nor clobbers an existing one). A log
damaged part-way is estimated up to the damage, with one line on stderr saying where.
On success one line on stderr says which magnetic declination the yaw is referred to and where it
came from: the vehicle's COMPASS_DEC / EKF2_MAG_DECL in the log (.tlog PARAM_VALUE, DataFlash PARM,
ULog parameters), else the World Magnetic Model
at the first 3D GPS fix, else none (magnetic north); a `--gain declination=...` wins over both.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TextIO

from tqdm import tqdm

from gcs.commands.common import load_preset_file, same_file
from gcs.core.declination import VehicleDeclination
from gcs.core.estimation import GainChange, run_estimator
from gcs.core.estimators import registry
from gcs.core.gains import GainError
from gcs.core.rotation import quat_to_euler
from gcs.core.samples import ImuSample
from gcs.logs.logfile import InputError, LogFile, no_imu_samples
from gcs.logs.readers import READERS, Sample, read_samples
from gcs.logs.tlog import read_tlog
from gcs.mavlink.sampling import MessageInputs
from gcs.mavlink.tlog import read_tlog_records
from gcs.sessions.export import write_beside

OUT_HEADER = "t,qw,qx,qy,qz,roll,pitch,yaw"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "input",
        nargs="?",
        help=f"a log ({', '.join(s for s in READERS if s != '.csv')}: MAVLink telemetry, DataFlash, PX4 ULog) "
        "or a .csv with header t,gx,gy,gz,ax,ay,az,mx,my,mz[,vn,ve,vd]",
    )
    parser.add_argument("--estimator", "-e", help="estimator name (see --list)")
    parser.add_argument("--preset", "-p", help="gain preset (default: the estimator's default)")
    parser.add_argument(
        "--preset-file", metavar="FILE", help="a preset file (TOML, as gcs sweep writes): estimator, preset and gains"
    )
    parser.add_argument("--gain", "-g", action="append", default=[], metavar="NAME=VALUE", help="override one gain")
    parser.add_argument("--imu", type=int, default=0, metavar="N", help="IMU instance (default 0, the first)")
    parser.add_argument("--out", "-o", help="output CSV path")
    parser.add_argument("--list", action="store_true", help="list estimators, presets and gains, then exit")


def describe(cls: type) -> str:
    """The first line of the estimator's readable reference's docstring: a compiled class's own
    says only that it is compiled, and over two lines."""
    from gcs.core.estimators.compiled import Compiled  # noqa: PLC0415  (loaded by registry.get already)

    reference = next(k for k in cls.__mro__ if not issubclass(k, Compiled))
    return (reference.__doc__ or "").strip().splitlines()[0]


def list_estimators() -> str:
    """Every registered estimator with its presets and gain declarations."""

    lines = []
    for name in registry.names():
        try:
            cls = registry.get(name)
        except Exception as exc:  # one broken module must not hide the others
            lines.append(f"{name}: unavailable ({exc})")
            continue
        lines.append(f"{name}: {describe(cls)}")
        presets = ", ".join(f"{p}{' (default)' if p == cls.DEFAULT_PRESET else ''}" for p in cls.PRESETS)
        lines.append(f"  presets: {presets}")
        for g in cls.GAINS:
            values = " ".join(f"{p}={v[g.name]:g}" for p, v in cls.PRESETS.items() if g.name in v)
            lines.append(
                f"  {g.name:<14} default {g.default:<8g} [{g.min:g}, {g.max:g}] {g.unit:<5} {g.meaning}"
                + (f" (presets: {values})" if values else "")
            )
    return "\n".join(lines)


def _parse_gains(items: list[str]) -> dict[str, float]:
    gains = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise ValueError(f"--gain {item!r}: expected NAME=VALUE")
        try:
            gains[name.strip()] = float(value)
        except ValueError:
            raise ValueError(f"--gain {item!r}: {value.strip()!r} is not a number") from None
    return gains


class Declination:
    """What the yaw is referred to: the last declination applied and where it came from."""

    def __init__(self, pinned: bool, value: float) -> None:
        self.source = "--gain declination" if pinned else "none (magnetic north)" if value == 0.0 else "the preset"
        self.value = value


def _noting(samples: Iterable[Sample], source: VehicleDeclination, declination: Declination) -> Iterator[Sample]:
    """The samples, noting each declination change the log's parameters (or WMM) give."""
    for item in samples:
        if isinstance(item, GainChange) and item.name == "declination" and not declination.source.startswith("--"):
            declination.value = item.value
            declination.source = source.source
        yield item


def estimate(input_path: str, estimator, out: TextIO, imu: int = 0, declination: Declination | None = None) -> int:
    """Feed every sample of input_path (IMU instance imu) to estimator, writing one row per IMU
    sample to out; afterwards one stderr line per damage or note the log reader reported. The
    declination a log gives (its parameters, else the WMM) is applied unless the estimator's
    `declination` gain was pinned."""

    declination = declination or Declination(False, estimator.gains["declination"])
    pinned = ("declination",) if declination.source.startswith("--") else ()
    out.write(OUT_HEADER + "\n")
    rows = 0
    deg = 57.29577951308232
    is_tlog = os.path.splitext(input_path)[1].lower() == ".tlog" and os.path.isfile(input_path)
    samples: Iterable[Sample]
    records = read_tlog_records(input_path) if is_tlog else None
    if records is not None:
        inputs = MessageInputs()
        samples, source = read_tlog(input_path, imu, inputs, records), inputs.vehicle_declination
    else:
        samples = read_samples(input_path, imu)
        source = samples.declination if isinstance(samples, LogFile) else VehicleDeclination()
    noted = _noting(samples, source, declination)
    shown = tqdm(noted, desc="estimate", unit=" samples", disable=not sys.stderr.isatty(), leave=True)
    for sample, _ in run_estimator(estimator, shown, pinned=pinned):
        if isinstance(sample, ImuSample):
            q = estimator.quaternion
            roll, pitch, yaw = quat_to_euler(q)
            out.write(
                f"{sample.t:.6f},{q[0]:.9f},{q[1]:.9f},{q[2]:.9f},{q[3]:.9f},"
                f"{roll * deg:.6f},{pitch * deg:.6f},{yaw * deg:.6f}\n"
            )
            rows += 1
    damage = records.damage("estimated up to it") if records is not None else None
    if isinstance(samples, LogFile):
        for note in samples.notes:
            print(f"gcs estimate: note: {note}", file=sys.stderr)
        damage = samples.damage
    if damage:
        print(f"gcs estimate: damage: {damage}", file=sys.stderr)
    return rows


def _fail(message: str) -> int:
    print(f"gcs estimate: error: {message}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:

    if args.list:
        print(list_estimators())
        return 0
    try:
        preset = load_preset_file(args.preset_file) if args.preset_file else None
    except (OSError, GainError) as exc:
        return _fail(str(exc) if isinstance(exc, GainError) else f"{args.preset_file}: {exc.strerror}")
    if preset is not None and args.estimator not in (None, preset.estimator):
        return _fail(f"--preset-file {args.preset_file} is for {preset.estimator}, not --estimator {args.estimator}")
    name: str = args.estimator or (preset.estimator if preset else "")
    for flag, value in (("INPUT", args.input), ("--estimator", name), ("--out", args.out)):
        if not value:
            return _fail(f"{flag} is required (or use --list)")
    if same_file(args.input, args.out):
        # a CSV in, a CSV out: the estimates replaced the samples they were made from
        return _fail(f"--out {args.out} is INPUT itself; give another file")
    try:
        gains = {**(preset.gains if preset else {}), **_parse_gains(args.gain)}
        estimator = registry.create(name, args.preset or (preset.preset if preset else None), **gains)
    except (KeyError, GainError, ValueError) as exc:
        return _fail(str(exc).strip("'\""))
    if args.imu < 0:
        return _fail(f"--imu {args.imu}: an IMU instance is 0 or more")
    declination = Declination("declination" in gains, estimator.gains["declination"])

    def write(tmp: Path) -> int:
        with open(tmp, "w", newline="") as out:
            rows = estimate(args.input, estimator, out, args.imu, declination)
        if rows == 0:
            raise no_imu_samples(args.input)  # OUT is left as it was
        return rows

    try:
        write_beside(Path(args.out), write)
    except InputError as exc:
        return _fail(str(exc))
    except OSError as exc:
        return _fail(f"{exc.filename or args.out}: {exc.strerror}")
    print(
        f"gcs estimate: declination {math.degrees(declination.value):.2f} deg from {declination.source}",
        file=sys.stderr,
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    """`python -m gcs.commands.estimate ...`: the same contract without the `gcs` entry point."""
    parser = argparse.ArgumentParser(prog="gcs estimate", description=__doc__.splitlines()[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
