"""`gcs params get|set|save|load|diff`: the vehicle's parameters from the command line.

`set` and `load` write through the same verified path as the tuning panel (each value echoed
back by the vehicle, or an error naming what it stored), and with `--profile` through the same
safety limits. A load skips the read-only and volatile parameters (param_files.not_loadable) with
a note each; with `--profile` it writes only the profile's tunables and notes the rest of the
file, and the tunables are checked together before the first write: nothing is written if any
of their values is refused.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path

from gcs.commands.common import os_error_line, progress_bar
from gcs.commands.options import add_link_arguments, station_config
from gcs.commands.vehicle_choice import add_sysid_argument, not_heard, one_vehicle
from gcs.mavlink import param_files
from gcs.mavlink.params import ParamError, format_value, type_name
from gcs.runtime.params import Param, ParamClient
from gcs.runtime.tuning import GLOBAL_PER_SECOND, ProfileError, TuningSession, available_profiles, load_profile
from gcs.sessions.export import write_beside

CLIENT = "cli"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)

    def action(name: str, text: str) -> argparse.ArgumentParser:
        return actions.add_parser(name, help=text, description=text)

    get = action("get", "print parameters (all of them when no NAME is given)")
    get.add_argument("names", nargs="*", metavar="NAME", help="parameter names (default: the whole table)")
    set_ = action("set", "write one parameter, verified by the vehicle's echo")
    set_.add_argument("name", metavar="NAME", help="the parameter, e.g. ATC_RAT_RLL_P")
    set_.add_argument("value", type=float, metavar="VALUE", help="the new value")
    save = action("save", "download the whole table into a Mission Planner/MAVProxy .param file")
    save.add_argument("file", metavar="FILE", help="the .param file to write")
    load = action("load", "write the values of a .param file that differ from the vehicle's, each verified")
    load.add_argument("file", metavar="FILE", help="the .param file to read")
    load.add_argument("--dry-run", action="store_true", help="only print what would change")
    diff = action("diff", "compare a .param file with the vehicle (--connect) or with another file (FILE2)")
    diff.add_argument("file", metavar="FILE", help="a .param file")
    diff.add_argument("other", nargs="?", metavar="FILE2", help="a second .param file (then no vehicle is needed)")
    for p in (set_, load):
        p.add_argument(
            "--profile",
            metavar="NAME|FILE",
            help=f"refuse values outside this tuning profile's limits ({', '.join(available_profiles())})",
        )
    for p in (get, set_, save, load, diff):
        # parameters only: no stream requests, no estimators; two files need no vehicle
        add_link_arguments(p, connect_required=p is not diff, streams=False, record="opt-in")
        add_sysid_argument(p)
    for p in (get, save, load, diff):
        p.add_argument("--timeout", type=float, default=120.0, help="seconds allowed for a full download")


def run(args: argparse.Namespace) -> int:
    try:
        if args.action == "diff" and args.other is not None:
            a, b = param_files.load(args.file), param_files.load(args.other)
            print(param_files.format_diff(param_files.diff(a, b), args.file, args.other))
            return 0
        if args.connect is None:
            raise ParamError("diff of one file needs --connect (the vehicle) or a second file")
        profile = load_profile(args.profile) if getattr(args, "profile", None) else None
        config = station_config(args)
    except (ParamError, ProfileError, ValueError) as exc:
        print(f"gcs params {args.action}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"gcs params {args.action}: error: {os_error_line(exc)}", file=sys.stderr)
        return 2
    config.request_streams = False  # keep the link for the parameter traffic
    config.estimate = False
    try:
        return asyncio.run(_with_station(config, args, profile))
    except (ParamError, ProfileError) as exc:
        print(f"gcs params {args.action}: error: {exc}", file=sys.stderr)
        return 1


async def _with_station(config, args, profile) -> int:
    async with one_vehicle(config, args.sysid) as (fleet, station):
        if not await station.link.wait_connected(15.0):
            raise ParamError(not_heard(fleet, 15.0))
        return await ACTIONS[args.action](station.params, args, profile)


async def _get(params, args, profile) -> int:
    found = (
        [await params.read(name) for name in args.names]
        if args.names
        else list((await downloaded(params, args.timeout)).values())
    )
    for p in sorted(found, key=lambda p: p.name):
        print(f"{p.name:<16} {format_value(p.value):>14}  {type_name(p.type)}")
    return 0


async def _set(params, args, profile) -> int:
    before = params.table.get(args.name) or await params.read(args.name)
    if profile is not None:
        stored = await TuningSession(params, profile).set(args.name, args.value, CLIENT)
    else:
        stored = await params.set(args.name, args.value, CLIENT)
    print(f"{args.name}: {format_value(before.value)} -> {format_value(stored.value)} (verified)")
    return 0


async def _save(params, args, profile) -> int:
    table = await downloaded(params, args.timeout)
    comment = f"{len(table)} parameters from {params.link.address}"
    try:  # written beside FILE and renamed: a full disk keeps the snapshot FILE held (it cut it short)
        write_beside(Path(args.file), lambda tmp: param_files.save(tmp, params.values(), comment=comment))
    except OSError as exc:
        raise ParamError(f"{os_error_line(exc, args.file)} (an earlier file is kept as it was)") from None
    print(f"saved {len(table)} parameters to {args.file}")
    return 0


async def _load(params, args, profile) -> int:
    wanted = param_files.load(args.file)
    await downloaded(params, args.timeout)
    unknown = sorted(set(wanted) - set(params.table))
    if unknown:
        raise ParamError(f"{args.file}: not parameters of this vehicle: {', '.join(unknown)}; nothing written")
    changes, skipped = param_files.split_loadable(
        param_files.diff(wanted, {name: params.table[name].value for name in wanted})
    )
    session = TuningSession(params, profile) if profile is not None else None
    if profile is not None:  # the tunables are written, the rest of the file is reported
        outside = [c for c in changes if c.name not in profile.params]
        skipped += [param_files.Skipped(c, f"not in the tuning profile {profile.name}") for c in outside]
        changes = [c for c in changes if c.name in profile.params]
        refused = []
        for change in changes:
            try:
                profile.check(change.name, change.a, change.b)
            except ParamError as exc:
                refused.append(str(exc))
        if refused:
            raise ParamError("refused by the tuning profile, nothing written:\n  " + "\n  ".join(refused))
    print(param_files.format_diff(changes, "file", "vehicle"))
    for skip in skipped:
        print(skip.note())
    if args.dry_run or not changes:
        return 0
    failed = []
    for i, change in enumerate(changes):
        if change.a is None:  # not in the file (never: only the file's names are compared)
            continue
        try:
            if session is not None:
                if i:
                    await asyncio.sleep(1.0 / GLOBAL_PER_SECOND)  # stay inside the profile's rate limit
                await session.set(change.name, change.a, CLIENT)
            else:
                await params.set(change.name, change.a, CLIENT)
        except ParamError as exc:
            failed.append(str(exc))
    print(
        f"wrote {len(changes) - len(failed)} of {len(changes)} parameters, each verified"
        + (f"; skipped {len(skipped)}" if skipped else "")
    )
    for line in failed:
        print(f"  FAILED {line}", file=sys.stderr)
    return 1 if failed else 0


async def _diff(params, args, profile) -> int:
    wanted = param_files.load(args.file)
    await downloaded(params, args.timeout)
    vehicle = {name: params.table[name].value for name in wanted if name in params.table}
    print(param_files.format_diff(param_files.diff(wanted, vehicle), args.file, "vehicle"))
    return 0


ACTIONS = {"get": _get, "set": _set, "save": _save, "load": _load, "diff": _diff}


async def downloaded(params: ParamClient, timeout: float) -> dict[str, Param]:
    """params.download(timeout), with a progress bar of the parameters received so far."""
    show = progress_bar("parameters")
    task = asyncio.create_task(params.download(timeout))
    while not task.done():
        progress = params.progress()
        if progress["state"] == "downloading" and progress.get("count"):
            show(min(progress["received"], progress["count"] - 1), progress["count"])
        await asyncio.wait({task}, timeout=0.2)
    table = task.result()
    show(len(table), max(len(table), 1))
    return table
