"""`gcs replay`: a session folder, .tlog, DataFlash .bin or PX4 .ulg through the estimators,
paced or as fast as possible, then the error table per estimator and reference."""

from __future__ import annotations

import argparse
import asyncio
import sys
import time
from typing import Any

from gcs.commands.common import progress_bar
from gcs.core.estimators import jit
from gcs.core.gains import GainError
from gcs.logs.logfile import InputError
from gcs.runtime.replay import ReplaySession, compiled, selection, session_table, whole_table
from gcs.sessions.sources import open_source


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", help="a session folder, or a .tlog, DataFlash .bin or PX4 .ulg file")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument("--speed", type=float, default=1.0, help="playback speed (default 1 = real time)")
    pace.add_argument("--fast", action="store_true", help="as fast as possible")
    parser.add_argument(
        "--estimator", "-e", action="append", metavar="NAME", help="run only this estimator (repeatable; default all)"
    )
    parser.add_argument(
        "--gain",
        "-g",
        action="append",
        default=[],
        metavar="[EST.]NAME=VALUE",
        help="override a gain (of EST, or of every selected estimator that has it)",
    )


def comparison_table(rows: list[dict[str, Any]]) -> list[str]:
    """Session RMS / max error per estimator per reference (runtime.replay.session_table's rows),
    degrees (roll, pitch, yaw)."""
    lines = [f"{'estimator':<10}{'reference':<10}{'n':>7}  {'RMS roll/pitch/yaw deg':<26}{'max roll/pitch/yaw deg'}"]
    for row in rows:
        lines.append(
            f"{row['estimator']:<10}{row['reference']:<10}{row['n']:>7}  "
            + " ".join(f"{v:7.2f}" for v in row["rms_deg"])
            + "   "
            + " ".join(f"{v:7.2f}" for v in row["max_deg"])
        )
    return lines


def run(args: argparse.Namespace) -> int:
    started = time.perf_counter()  # end to end: numba's set-up and decoding the file count too
    jit.set_up()
    set_up = time.perf_counter() - started
    try:
        names, gains = selection(args.estimator, args.gain)
        source = open_source(args.path)
        session = ReplaySession(source, 0 if args.fast else args.speed, names, gains)
    except (InputError, KeyError, GainError, ValueError) as exc:
        print(f"gcs replay: error: {exc.args[0] if isinstance(exc, KeyError) else exc}", file=sys.stderr)
        return 2
    print(
        f"{source.kind} {source.path}: {len(source.frames)} frames, {source.duration:.1f} s, "
        f"{sum(source.counts.values())} messages/records",
        file=sys.stderr,
    )
    decoded = time.perf_counter() - started - set_up
    if args.fast and compiled(names):  # nothing watches the frames: each estimator over whole arrays
        rows, imu_samples = whole_table(source, names, gains, progress_bar("replay"))
    else:
        if args.fast:
            session.run_to_end(progress_bar("replay"))
        else:
            asyncio.run(_paced(session))
        rows, imu_samples = session_table(session.pipeline), session.pipeline.imu_samples
    elapsed = time.perf_counter() - started
    print("\n".join(comparison_table(rows)))
    print(
        f"replayed {source.duration:.1f} s in {elapsed:.2f} s ({source.duration / max(elapsed, 1e-9):.1f}x real time, "
        f"end to end: numba's set-up {set_up:.2f} s, decoding {decoded:.2f} s, estimators "
        f"{elapsed - set_up - decoded:.2f} s); {imu_samples} IMU samples"
    )
    if source.damage:
        print(f"damage: {source.damage}", file=sys.stderr)
    return 0


async def _paced(session: ReplaySession) -> None:
    task = asyncio.create_task(session.run())
    show = progress_bar("replay")
    try:
        while not session.finished.is_set():
            await asyncio.sleep(1.0)
            show(session.position, len(session.source.frames))
        show(len(session.source.frames), len(session.source.frames))
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
