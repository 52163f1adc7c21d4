"""`gcs protocol`: a guided bench-test protocol on a live vehicle (`run`), its tables from a
recorded session (`report`), and the shipped protocols (`list`)."""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path

from gcs.commands.common import run_reporting_errors
from gcs.commands.options import add_link_arguments, station_config_or_report
from gcs.commands.vehicle_choice import add_sysid_argument, not_heard
from gcs.core.gains import GainError
from gcs.core.protocol import ProtocolError, ProtocolTables, SourceMetrics, StepWindow
from gcs.runtime.fleet import Fleet
from gcs.runtime.protocol import LiveProtocol, ProtocolState
from gcs.runtime.replay import parse_gains
from gcs.runtime.station import StationConfig
from gcs.sessions.contents import open_contents
from gcs.sessions.export import write_protocol_csv
from gcs.sessions.protocol import available_protocols, formatted, load_protocol, session_tables

#: The protocol results written into the session folder at the end of a run.
RESULTS_NAME = "protocol.csv"

#: Seconds to wait for the vehicle `--sysid` names (or --timeout if less) before giving up;
#: without --sysid the run waits for the first vehicle.
SYSID_WAIT = 15.0

_KEYS = """\
keys during a run (type the letter, then Enter):
  s   skip the current step      r   repeat the previous step      q   end the run now
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    run_parser = sub.add_parser(
        "run",
        help="prompt each step, detect the holds, score every source",
        description="run a test protocol against a vehicle: prompt each step, detect the holds, score every source",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=_KEYS,
    )
    run_parser.add_argument("protocol", help=f"a shipped protocol ({', '.join(available_protocols())}) or a TOML file")
    add_link_arguments(run_parser)
    add_sysid_argument(run_parser)
    run_parser.add_argument(
        "--detect-source", default=None, help="source whose attitude detects the holds (default: the protocol's)"
    )
    run_parser.add_argument(
        "--preset",
        action="append",
        default=[],
        metavar="EST=PRESET",
        help="start an estimator from a preset, e.g. dcm=seed000 (recorded as gain changes), repeatable",
    )
    run_parser.add_argument(
        "-g",
        "--gain",
        action="append",
        default=[],
        metavar="[EST.]NAME=VALUE",
        help="set an estimator gain at the start (recorded as a gain change), repeatable",
    )
    run_parser.add_argument(
        "--timeout", type=float, default=None, help="give up after this many seconds (default: wait for every step)"
    )
    report_parser = sub.add_parser(
        "report",
        help="the protocol tables of a recorded session",
        description="the protocol tables of a recorded session",
    )
    report_parser.add_argument("session", help="a session folder with a protocol run")
    report_parser.add_argument("--csv", default=None, metavar="FILE", help="also write the tables as CSV")
    sub.add_parser("list", help="the shipped protocols", description="list the shipped protocols, one a line")


def run(args: argparse.Namespace) -> int:
    if args.action == "list":
        for name in available_protocols():
            protocol = load_protocol(name)
            print(f"{name:<20} {len(protocol.steps)} steps  {protocol.description}")
        return 0
    if args.action == "report":
        return _report(args)
    try:
        load_protocol(args.protocol)  # a bad file is refused before connecting
    except ProtocolError as exc:
        print(f"gcs protocol: {exc}", file=sys.stderr)
        return 2
    config = station_config_or_report(args, "protocol")
    if config is None:
        return 2
    return asyncio.run(_run(config, args))


def _report(args: argparse.Namespace) -> int:
    def work() -> str:
        tables = session_tables(open_contents(args.session))
        if tables is None:
            raise ProtocolError(f"{args.session}: no protocol run in this session")
        print(format_tables(tables))
        if args.csv:
            write_protocol_csv(tables, args.csv)
            return f"wrote {args.csv}"
        return ""

    try:
        return run_reporting_errors("protocol", args.csv or args.session, work)
    except ProtocolError as exc:
        print(f"gcs protocol: {exc}", file=sys.stderr)
        return 2


async def _run(config: StationConfig, args: argparse.Namespace) -> int:
    fleet = Fleet(config, single=True, sysid=args.sysid)
    station = fleet.first
    try:
        gains = parse_gains(args.gain, station.estimator_names())
    except ValueError as exc:
        print(f"gcs protocol: {exc}", file=sys.stderr)
        return 2
    await fleet.start()
    wait = min(SYSID_WAIT, args.timeout or SYSID_WAIT)
    if args.sysid is not None and not await station.link.wait_connected(wait):
        print(f"gcs protocol: {not_heard(fleet, wait)}", file=sys.stderr)
        await fleet.stop()
        return 1
    try:  # once recording: the session's events carry the changes, where they were applied
        for item in args.preset:
            estimator, sep, preset = item.partition("=")
            if not sep:
                raise GainError(f"--preset {item!r}: expected EST=PRESET")
            station.reset_gains(estimator.strip(), preset.strip(), "cli")
        for estimator, values in gains.items():
            for name, value in values.items():
                station.set_gain(estimator, name, value, "cli")
    except (KeyError, GainError) as exc:
        print(f"gcs protocol: {exc}", file=sys.stderr)
        await fleet.stop()
        return 2
    live = station.start_protocol(args.protocol, args.detect_source, "cli")
    done = asyncio.Event()
    live.changed.connect(lambda state: _prompt(state, done))
    live.step_done.connect(_print_step)
    _prompt(live.state(), done)
    stop_keys = _listen_to_keys(live, done)
    try:
        await asyncio.wait_for(done.wait(), args.timeout)
    except TimeoutError:
        print(f"gcs protocol: gave up after {args.timeout:g} s at step {live.index + 1}", file=sys.stderr)
    finally:
        stop_keys()
        live.finish()
        session = station.recorder.session if station.recorder is not None else None
        await fleet.stop()
    complete = live.finished and not live.skipped
    if session is None:
        print("gcs protocol: not recorded (--no-record): no tables", file=sys.stderr)
        return 0 if complete else 1
    tables = await asyncio.to_thread(session_tables, open_contents(session.folder))
    if tables is not None:
        print(format_tables(tables))
        out = Path(session.folder) / RESULTS_NAME
        await asyncio.to_thread(write_protocol_csv, tables, out)
        print(f"gcs protocol: session {session.folder}, tables in {out}", file=sys.stderr)
    return 0 if complete else 1


def _prompt(state: ProtocolState, done: asyncio.Event) -> None:
    if state.finished:
        done.set()
        return
    again = f" (attempt {state.attempt})" if state.attempt > 1 else ""
    print(f"step {state.step + 1}/{state.steps}{again}: {state.prompt}", flush=True)


def _print_step(window: StepWindow, metrics: list[SourceMetrics]) -> None:
    figures = "  ".join(f"{m.source} {m.mre_last_pct:.2f} %" for m in metrics)
    print(
        f"  held {window.t_hold_start:.2f}–{window.t_hold_end:.2f} s; mean relative error, last samples: {figures}",
        flush=True,
    )


def _listen_to_keys(live: LiveProtocol, done: asyncio.Event):
    """Read the operator's keys from stdin on the loop; returns the function that stops it.
    Without a readable stdin (a closed or empty pipe) the run is unattended."""
    loop = asyncio.get_running_loop()
    try:
        fd = sys.stdin.fileno()
        loop.add_reader(fd, lambda: _key(sys.stdin.readline(), live, done, stop))
    except (AttributeError, OSError, ValueError, NotImplementedError):
        return lambda: None

    def stop() -> None:
        loop.remove_reader(fd)

    return stop


def _key(line: str, live: LiveProtocol, done: asyncio.Event, stop) -> None:
    if not line:  # end of input: unattended from here on
        stop()
        return
    key = line.strip().lower()[:1]
    if key == "s":
        live.skip()
    elif key == "r":
        live.repeat()
    elif key == "q":
        done.set()


def format_tables(tables: ProtocolTables) -> str:
    """Seed 000's table (mean relative error per step and per axis) and seed 004's (MSE per axis,
    reduction relative to the raw accelerometer/magnetometer angles), as text."""
    sources = list(dict.fromkeys(m.source for m in tables.steps))
    labels = list(dict.fromkeys(m.label for m in tables.steps))
    last = tables.protocol.last_samples
    lines = [f"protocol {tables.protocol.name}: mean relative error over the last {last} samples, %"]
    lines.append(f"{'step':<22}" + "".join(f"{s:>11}" for s in sources))
    by = {(m.label, m.source): m for m in tables.steps}
    for label in labels:
        cells = [formatted(by[label, s].mre_last_pct, 2) if (label, s) in by else "–" for s in sources]
        lines.append(f"{label:<22}" + "".join(f"{c:>11}" for c in cells))
    means = {(m.axis, m.source): m for m in tables.axis_means}
    for axis in ("roll", "pitch", "yaw"):
        cells = [formatted(means[axis, s].mre_last_pct, 2) if (axis, s) in means else "–" for s in sources]
        lines.append(f"{axis + ' mean':<22}" + "".join(f"{c:>11}" for c in cells))
    lines.append("MSE per axis over the holds, deg² (reduction vs accel/mag angles, %)")
    for row in tables.mse:
        mse = "  ".join(formatted(v, 4) for v in (row.mse_roll, row.mse_pitch, row.mse_yaw))
        reductions = (row.reduction_roll_pct, row.reduction_pitch_pct, row.reduction_yaw_pct)
        red = "  ".join(formatted(v, 1) for v in reductions)
        lines.append(f"{row.source:<12} {mse}   ({red})")
    return "\n".join(lines)
