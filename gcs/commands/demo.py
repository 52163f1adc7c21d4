"""`gcs demo`: the simulated vehicle and the ground station together, so the first command a
user runs shows a working system with no hardware."""

from __future__ import annotations

import argparse
import asyncio
import math
import sys

from gcs.commands.common import os_error_line
from gcs.commands.options import add_record_arguments, recording
from gcs.commands.serve import add_server_arguments, announce, dashboard, presets_or_report
from gcs.commands.sim import PROFILES
from gcs.core.gains import PresetFile
from gcs.runtime import event_loop
from gcs.runtime.fleet import Fleet
from gcs.runtime.station import Station, StationConfig
from gcs.sim import SimVehicle
from gcs.transport.address import free_port


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--profile",
        choices=PROFILES,
        default="pixhawk",
        help="which autopilot the simulator behaves as (default pixhawk)",
    )
    parser.add_argument(
        "--script",
        choices=("bench", "circuit", "quad"),
        default="quad",
        help="the simulated motion (default quad: a flight with coordinated turns)",
    )
    parser.add_argument(
        "--vehicles",
        type=vehicle_list,
        default=None,
        metavar="PROFILE:SYSID,...",
        help="several simulated vehicles on the one link, e.g. apm25:1,pixhawk:2 (default: one --profile, sysid 1)",
    )
    parser.add_argument("--seed", type=int, default=0, help="simulator random seed")
    parser.add_argument(
        "--out",
        action="append",
        default=[],
        metavar="URL",
        help="also forward the vehicle to this address (e.g. udpout:127.0.0.1:14550 for QGC)",
    )
    parser.add_argument(
        "--duration", type=float, default=0.0, help="stop after this many seconds (0: run until Ctrl-C)"
    )

    add_record_arguments(parser)
    add_server_arguments(parser)


def vehicle_list(text: str) -> list[tuple[str, int]]:
    """`apm25:1,pixhawk:2` → [("apm25", 1), ("pixhawk", 2)]; argparse reports a bad one."""
    vehicles = []
    for item in text.split(","):
        profile, _, sysid = item.strip().partition(":")
        if profile not in PROFILES or not sysid.isdigit() or not 1 <= int(sysid) <= 254:
            raise argparse.ArgumentTypeError(f"{item!r}: give PROFILE:SYSID, PROFILE one of {', '.join(PROFILES)}")
        vehicles.append((profile, int(sysid)))
    if len({sysid for _, sysid in vehicles}) < len(vehicles):
        raise argparse.ArgumentTypeError(f"{text!r}: each vehicle needs a system id of its own")
    return vehicles


def run(args: argparse.Namespace) -> int:
    if not (args.duration >= 0 and math.isfinite(args.duration)):  # -1 or nan ran until Ctrl-C
        print(f"gcs demo: --duration {args.duration!r}: give seconds >= 0 (0: run until Ctrl-C)", file=sys.stderr)
        return 2
    presets = presets_or_report(args, "demo")
    if presets is None:
        return 2
    try:
        event_loop.run(_demo(args, presets))
    except KeyboardInterrupt:
        pass
    except OSError as exc:  # a taken --port: one line, as `gcs serve` says it
        print(f"gcs demo: error: {os_error_line(exc)}", file=sys.stderr)
        return 2
    return 0


async def _demo(args: argparse.Namespace, presets: list[PresetFile]) -> None:

    port = free_port()
    config = StationConfig(
        f"udpin:127.0.0.1:{port}",
        outputs=args.out,
        sessions_dir=args.record_dir,
        record=recording(args),
        presets=presets,
    )
    fleet = Fleet(config)
    vehicles = args.vehicles or [(args.profile, 1)]
    sims = [SimVehicle(profile=p, script=args.script, seed=args.seed + i, sysid=n) for i, (p, n) in enumerate(vehicles)]
    names = ", ".join(f"{p} (sysid {n})" for p, n in vehicles)
    print(f"gcs demo: simulated {names} ({args.script}) on udp 127.0.0.1:{port}; Ctrl-C to stop", flush=True)

    server = dashboard(fleet, args)
    await fleet.start()
    sim_tasks = [asyncio.create_task(sim.run(f"udpout:127.0.0.1:{port}")) for sim in sims]
    await server.start()
    announce("demo", server)
    loop = asyncio.get_running_loop()
    stop_at = loop.time() + args.duration if args.duration > 0 else math.inf
    try:
        while loop.time() < stop_at:
            await asyncio.sleep(1.0)
            for entry in fleet.vehicles():
                prefix = f"sysid {entry.sysid}: " if len(sims) > 1 else ""
                print(prefix + _status_line(entry.station), flush=True)
    finally:
        for task in sim_tasks:
            task.cancel()
        await server.stop()
        await fleet.stop()
        await asyncio.gather(*sim_tasks, return_exceptions=True)


def _status_line(station: Station) -> str:
    """Link state and rates, then each source's roll/pitch/yaw, and each estimator's RMS
    error against the truth (or the onboard attitude when there is no truth)."""
    rates = station.link.stats.rates()
    parts = [
        f"link {station.link.state}",
        " ".join(
            f"{name} {rates[name]:.0f}Hz"
            for name in ("RAW_IMU", "HIGHRES_IMU", "ATTITUDE", "GPS_RAW_INT")
            if rates.get(name)
        ),
    ]
    estimation = station.snapshot.estimation
    if estimation is None:
        return " | ".join(p for p in parts if p)
    for source, a in estimation.latest.items():
        text = f"{source} {a.roll_deg:6.1f} {a.pitch_deg:6.1f} {a.yaw_deg:6.1f}"
        errors = estimation.estimators[source].errors if source in estimation.estimators else {}
        for reference in ("truth", "onboard"):
            rms = errors[reference].window_rms_deg if reference in errors else None
            if rms and None not in rms:
                text += f" (rms vs {reference} {rms[0]:.1f}/{rms[1]:.1f}/{rms[2]:.1f})"
                break
        parts.append(text)
    return " | ".join(p for p in parts if p)
