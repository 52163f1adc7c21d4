"""`gcs replay`: a session folder, .tlog, DataFlash .bin or PX4 .ulg through the estimators,
paced or as fast as possible, then the error table per estimator and reference."""

from __future__ import annotations

import argparse
import asyncio
import sys
import time

from gcs.commands.common import progress_bar
from gcs.core.estimation import EstimationPipeline
from gcs.core.gains import GainError
from gcs.logs.logfile import InputError
from gcs.runtime.replay import ReplaySession, selection
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


def comparison_table(pipeline: EstimationPipeline) -> list[str]:
    """Session RMS / max error per estimator per reference, degrees (roll, pitch, yaw)."""
    lines = [f"{'estimator':<10}{'reference':<10}{'n':>7}  {'RMS roll/pitch/yaw deg':<26}{'max roll/pitch/yaw deg'}"]
    for name, comparison in pipeline.comparisons.items():
        for ref, stats in comparison.summary()["references"].items():
            s = stats["session"]
            lines.append(
                f"{name:<10}{ref:<10}{s['n']:>7}  "
                + " ".join(f"{v:7.2f}" for v in s["rms"])
                + "   "
                + " ".join(f"{v:7.2f}" for v in s["max"])
            )
    return lines


def run(args: argparse.Namespace) -> int:
    started = time.perf_counter()  # end to end: decoding the file counts too
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
    decoded = time.perf_counter() - started
    if args.fast:
        session.run_to_end(progress_bar("replay"))
    else:
        asyncio.run(_paced(session))
    elapsed = time.perf_counter() - started
    print("\n".join(comparison_table(session.pipeline)))
    print(
        f"replayed {source.duration:.1f} s in {elapsed:.2f} s ({source.duration / max(elapsed, 1e-9):.1f}x real time); "
        f"{session.pipeline.imu_samples} IMU samples (decoding {decoded:.2f} s of it)"
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
