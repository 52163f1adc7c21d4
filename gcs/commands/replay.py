"""`gcs replay`: a session folder, .tlog, DataFlash .bin or PX4 .ulg through the estimators,
paced or as fast as possible, then the error table per estimator and reference."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import sys
import time
from typing import Any

from gcs.commands.common import os_error_line, progress_bar
from gcs.commands.options import check_speed
from gcs.core.comparison import MIN_IMU_RATE, imu_rate_of, reliability
from gcs.core.estimators import jit, whole
from gcs.core.gains import GainError
from gcs.logs import dataflash_format, ulog_format
from gcs.logs.logfile import InputError
from gcs.runtime.estimation import warm
from gcs.runtime.replay import ReplaySession, compiled, selection, session_table, whole_table
from gcs.sessions.sources import ReplaySource, open_source


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("path", help="a session folder, or a .tlog, DataFlash .bin or text .log, or PX4 .ulg file")
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
    started = time.perf_counter()
    try:
        check_speed(args.speed)
        names, gains = selection(args.estimator, args.gain)
    except (KeyError, GainError, ValueError) as exc:
        return _error(exc)
    whole_runs = args.fast and compiled(names)  # nothing watches the frames: each estimator over whole arrays
    _start_up(whole_runs)
    ready = time.perf_counter()
    try:
        source = open_source(args.path)
        source.require_imu()  # as `gcs estimate`: no table of nothing, exit 0
        session = ReplaySession(source, 0 if args.fast else args.speed, names, gains)
    except (InputError, KeyError, GainError, ValueError, OSError) as exc:  # OSError: a session's file unreadable
        return _error(exc)
    print(
        f"{source.kind} {source.path}: {len(source.frames)} frames, {source.duration:.1f} s, "
        f"{sum(source.counts.values())} messages/records",
        file=sys.stderr,
    )
    decoded = time.perf_counter()
    if whole_runs:
        rows, imu_samples = whole_table(source, names, gains, progress_bar("replay"))
    else:
        if args.fast:
            session.run_to_end(progress_bar("replay"))
        else:
            asyncio.run(_paced(session))
        rows, imu_samples = session_table(session.pipeline), session.pipeline.imu_samples
    done = time.perf_counter()
    print("\n".join(comparison_table(rows)))
    replay, start_up = done - ready, ready - started
    print(
        f"replayed {source.duration:.1f} s in {replay:.2f} s ({source.duration / max(replay, 1e-9):.1f}x real time, "
        f"end to end: decoding {decoded - ready:.2f} s, estimators {done - decoded:.2f} s); "
        f"start-up {start_up:.2f} s (numba's set-up and compiled kernels; "
        f"{source.duration / max(done - started, 1e-9):.1f}x real time with it); {imu_samples} IMU samples"
    )
    if source.damage:
        print(f"damage: {source.damage}", file=sys.stderr)
    for note in source.notes:  # as `gcs estimate` says them: what explains a heading's errors
        print(f"gcs replay: note: {note}", file=sys.stderr)
    slow = imu_rate_note(source)
    if slow:
        print(f"gcs replay: note: {slow}", file=sys.stderr)
    return 0


def imu_rate_note(source: ReplaySource) -> str | None:
    """What makes the table above no fair comparison, as the live status and `gcs report` say it:
    the log's raw IMU (its mean rate) too slow for a ground-side estimator to follow the motion."""
    t = source.table.imu[:, 0]
    rate = imu_rate_of(len(t), len(t), float(t[0]), float(t[-1]))
    reliable, reason = reliability(rate, MIN_IMU_RATE)
    return None if reliable else f"{reason} (the errors above are not a fair comparison)"


def _start_up(whole_runs: bool) -> None:
    """What a replay pays once per process whatever the log: numba's set-up and loading the
    kernels it runs (the decoders' and the estimators') from the disk cache, or compiling them the
    first time. Printed apart, so that the speed printed is the replay's own, file to table."""
    jit.set_up()
    ulog_format.warm()
    dataflash_format.warm()
    (whole.warm if whole_runs else warm)()


def _error(exc: Exception) -> int:
    text = exc.args[0] if isinstance(exc, KeyError) else os_error_line(exc) if isinstance(exc, OSError) else exc
    print(f"gcs replay: error: {text}", file=sys.stderr)
    return 2


async def _paced(session: ReplaySession) -> None:
    task = asyncio.create_task(session.run())
    show = progress_bar("replay")
    try:
        while not session.finished.is_set():
            # the bar moves once a second; the end is seen at once (a sleep of 1 s saw it up to a
            # second late, and that second went into the time and the "x real time" printed)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(session.finished.wait(), 1.0)
            show(session.position, len(session.source.frames))
        show(len(session.source.frames), len(session.source.frames))
    finally:
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
