"""`gcs logs list|download [N|latest]`: the vehicle's onboard DataFlash logs over the link.

A download shows its progress and rate, re-requests what was lost, resumes a download cut by a
link drop on the next run (the partial file is kept beside the target), and ends with the
commands that replay the log through the estimators at full rate.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import time
from collections.abc import Callable
from pathlib import Path

from gcs.commands.common import progress_bar
from gcs.commands.options import add_link_arguments, station_config_or_report
from gcs.commands.vehicle_choice import add_sysid_argument, not_heard, one_vehicle
from gcs.mavlink.logtransfer import LogEntry
from gcs.runtime.logdownload import LogDownloader, LogDownloadError, LogDownloadProgress

#: Seconds between progress lines when stderr is not a terminal.
REPORT_INTERVAL = 5.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    list_ = actions.add_parser(
        "list",
        help="list the logs on the vehicle (id, size, date)",
        description="list the logs on the vehicle (id, size, date)",
    )
    download = actions.add_parser(
        "download",
        help="download one log (byte-identical, resumable)",
        description="download one log (byte-identical, resumable)",
    )
    download.add_argument("log", nargs="?", default="latest", metavar="N|latest", help="log id (default latest)")
    download.add_argument(
        "--out", dest="folder", default="logs", metavar="DIR", help="folder for the log (default ./logs)"
    )
    for p in (list_, download):
        # the link options of the other link commands (--baud auto, --heartbeat-timeout, signing: a
        # signing vehicle refuses the unsigned LOG_REQUEST_* and the station its packets)
        add_link_arguments(p, streams=False, record="never", forward=False)
        p.add_argument("--timeout", type=float, default=15.0, help="seconds to wait for the vehicle (default 15)")
        add_sysid_argument(p)


def run(args: argparse.Namespace) -> int:
    if args.action == "download" and args.log != "latest" and not (args.log.isdigit() and int(args.log) > 0):
        print(f"gcs logs {args.action}: log {args.log!r}: give a log id (1, 2, ...) or 'latest'", file=sys.stderr)
        return 2
    config = station_config_or_report(args, f"logs {args.action}")
    if config is None:
        return 2
    config.request_streams, config.estimate = False, False
    try:
        return asyncio.run(_with_station(config, args))
    except LogDownloadError as exc:
        print(f"gcs logs {args.action}: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # the output folder: unwritable, full (the partial file is kept)
        where = exc.filename or getattr(args, "folder", None)  # `list` has no folder
        print(f"gcs logs {args.action}: error: {f'{where}: ' if where else ''}{exc.strerror or exc}", file=sys.stderr)
        return 1


async def _with_station(config, args) -> int:
    async with one_vehicle(config, args.sysid) as (fleet, station):
        if not await station.link.wait_connected(args.timeout):
            raise LogDownloadError(not_heard(fleet, args.timeout))
        downloader = LogDownloader(station.link)
        entries = await downloader.list_logs(args.timeout)
        if args.action == "list":
            print(format_list(entries))
            return 0
        entry = pick(entries, args.log)
        path = await downloader.download(entry, Path(args.folder), progress_reporter(entry.id))
        print(format_done(downloader.progress))
        print(f"replay it: gcs replay {path} --fast   or   gcs estimate {path} -e ekf --out est.csv")
        return 0


def progress_reporter(log_id: int) -> Callable[[LogDownloadProgress], None]:
    """A bar on a terminal; elsewhere (CI, pipes) a line on stderr every REPORT_INTERVAL s."""
    if sys.stderr.isatty():
        show = progress_bar(f"log {log_id}")
        return lambda p: show(p.bytes_received, p.size)
    last = [0.0]

    def report(p: LogDownloadProgress) -> None:
        if p.elapsed_s - last[0] >= REPORT_INTERVAL:
            last[0] = p.elapsed_s
            print(f"gcs logs download: {format_progress(p)}", file=sys.stderr, flush=True)

    return report


def format_progress(p: LogDownloadProgress) -> str:
    return (
        f"log {p.log_id}: {100 * p.fraction:.0f} %, {p.bytes_received} of {p.size} bytes, "
        f"{p.rate_bps / 1000:.1f} kB/s, {p.re_requests} re-requests"
    )


def pick(entries: list[LogEntry], which: str) -> LogEntry:
    if not entries:
        raise LogDownloadError("the vehicle has no logs")
    if which == "latest":
        return entries[-1]
    for entry in entries:
        if entry.id == int(which):
            return entry
    raise LogDownloadError(f"no log {which}; the vehicle has {', '.join(str(e.id) for e in entries)}")


def format_list(entries: list[LogEntry]) -> str:
    lines = [f"{'id':>4} {'size':>12}  date (UTC)"]
    for e in entries:
        date = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(e.time_utc)) if e.time_utc else "-"
        lines.append(f"{e.id:>4} {e.size:>12}  {date}")
    return "\n".join(lines) if entries else "the vehicle has no logs"


def format_done(p: LogDownloadProgress) -> str:
    resumed = f", {p.resumed_bytes} resumed from a partial download" if p.resumed_bytes else ""
    return (
        f"log {p.log_id}: {p.size} bytes in {p.elapsed_s:.1f} s ({p.rate_bps / 1000:.1f} kB/s), "
        f"{p.re_requests} re-requests{resumed} -> {p.path}"
    )
