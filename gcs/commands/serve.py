"""`gcs serve`: connect to a vehicle and serve the browser dashboard (live plots, 3-D pose view,
gain sliders) and its REST/WebSocket API."""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import os
import sys

from gcs.commands.common import load_preset_file, os_error_line
from gcs.commands.options import add_link_arguments, links_of, station_config_or_report
from gcs.core.estimation import pipeline_from
from gcs.core.gains import GainError, PresetFile
from gcs.runtime import event_loop
from gcs.runtime.fleet import Fleet
from gcs.runtime.priority import raise_priority
from gcs.server.dashboard import DashboardServer
from gcs.server.live import LiveHub


def add_server_arguments(parser: argparse.ArgumentParser) -> None:
    """The dashboard options `gcs serve` and `gcs demo` share."""
    parser.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to serve on (default 127.0.0.1: this machine only)",
    )
    parser.add_argument(
        "--token",
        default=os.environ.get("GCS_TOKEN"),
        help="the token every change (gains, parameters, recording, replay) needs (default: $GCS_TOKEN, else a "
        "new random one); printed in the start-up URL",
    )
    parser.add_argument("--port", type=int, default=8000, help="dashboard port (default 8000)")
    parser.add_argument(
        "--viser-port", type=int, default=None, help="3-D view port (default: dashboard port + 1, or the next free one)"
    )
    parser.add_argument(
        "--allow-origin",
        action="append",
        default=[],
        metavar="URL",
        help="also accept requests from pages of this origin, e.g. http://laptop.local:8080 (repeatable)",
    )
    parser.add_argument(
        "--history", type=float, default=600.0, help="seconds of every source kept for newly opened pages (default 600)"
    )
    parser.add_argument(
        "--preset-file",
        action="append",
        default=[],
        metavar="FILE",
        help="start that estimator from a preset file's preset and gains (gcs sweep writes them; repeatable)",
    )


def presets_or_report(args: argparse.Namespace, command: str) -> list[PresetFile] | None:
    """The --preset-file files, checked by building the estimators from them; None after one
    line on stderr saying what is wrong."""
    try:
        presets = [load_preset_file(path) for path in args.preset_file]
        pipeline_from(presets)
    except (OSError, KeyError, GainError) as exc:
        text = f"{exc.filename}: {exc.strerror}" if isinstance(exc, OSError) else str(exc).strip("'\"")
        print(f"gcs {command}: error: {text}", file=sys.stderr)
        return None
    return presets


def add_arguments(parser: argparse.ArgumentParser) -> None:

    add_link_arguments(parser, several=True)
    add_server_arguments(parser)
    parser.add_argument(
        "--nice",
        type=int,
        default=0,
        help="run the station at this nice value when the system permits it, e.g. -5: ahead of ordinary "
        "programs, for a busy machine whose viewers are elsewhere (default 0: the priority is left alone)",
    )


def run(args: argparse.Namespace) -> int:

    config = station_config_or_report(args, "serve")
    presets = presets_or_report(args, "serve")
    if config is None or presets is None:
        return 2
    config = dataclasses.replace(config, presets=presets)
    if args.nice:
        print(f"gcs serve: {raise_priority(args.nice)}", flush=True)
    try:
        event_loop.run(_serve(config, args))
    except OSError as exc:
        print(f"gcs serve: error: {os_error_line(exc)}", file=sys.stderr)
        return 2
    return 0


def dashboard(fleet: Fleet, args: argparse.Namespace) -> DashboardServer:
    """A DashboardServer for the parsed options (not started): every vehicle of the fleet, the
    first one at the one-vehicle URLs."""

    return DashboardServer(
        fleet.first,
        args.host,
        args.port,
        fleet=fleet,
        viser_port=args.viser_port,
        hub=LiveHub(seconds=args.history),
        allow_origins=tuple(args.allow_origin),
        token=args.token,
    )


def announce(command: str, server: DashboardServer, tail: str = "") -> None:
    """The start-up lines: the URL on this machine, and bound to every interface (--host 0.0.0.0)
    the URLs a teammate's laptop opens."""
    print(f"gcs {command}: dashboard at {server.url}  (3-D view on port {server.viser_port}){tail}", flush=True)
    if server.shared_urls:
        print(f"gcs {command}: from other machines: {'  '.join(server.shared_urls)}", flush=True)


async def _serve(config, args: argparse.Namespace) -> None:

    fleet = Fleet(config, links_of(args))
    server = dashboard(fleet, args)
    await fleet.start()
    try:
        await server.start()
        announce("serve", server, "; Ctrl-C to stop")
        await asyncio.Event().wait()
    finally:
        await server.stop()
        await fleet.stop()
