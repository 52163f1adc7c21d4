"""`gcs status`: connect, request streams, and print what a field engineer checks first."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys

from gcs.commands.options import add_link_arguments, station_config_or_report
from gcs.runtime.station import GroundStation


def add_arguments(parser: argparse.ArgumentParser) -> None:

    add_link_arguments(parser)
    parser.add_argument("--duration", type=float, default=10.0, help="seconds to listen (default 10)")
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def run(args: argparse.Namespace) -> int:

    config = station_config_or_report(args, "status")
    if config is None:
        return 2
    report = asyncio.run(_collect(config, args.duration))
    if args.json:
        json.dump(report, sys.stdout, indent=2)
        print()
    else:
        print(format_report(report))
    return 0 if report["vehicle"]["heartbeats"] else 1


async def _collect(config, duration: float) -> dict:

    station = GroundStation(config)
    await station.start()
    try:
        await asyncio.sleep(duration)
    finally:
        report = station.status()
        await station.stop()
    return report


def format_report(report: dict) -> str:
    link, vehicle, streams = report["link"], report["vehicle"], report["streams"]
    stats = link["stats"]
    lines = [
        f"link       {link['address']}  state {link['state']}  heartbeat age {link['heartbeat_age_s']} s",
        f"vehicle    sysid {vehicle['sysid']}  {vehicle['autopilot']}  {vehicle['vehicle_type']}  "
        f"MAVLink {vehicle['mavlink_version']}  {'ARMED' if vehicle['armed'] else 'disarmed'}  "
        f"firmware {vehicle['firmware'] or '?'}",
        f"traffic    {stats['packets']} packets  {stats['bytes_per_s']:.0f} B/s  CRC errors {stats['crc_errors']}  "
        f"malformed {stats['malformed']}  lost {stats['packets_lost']} ({100 * stats['loss_fraction']:.2f} %)",
        f"streams    via {streams['method']}  ({streams['requests_sent']} requests sent)",
    ]
    for name, row in streams["messages"].items():
        ack = f"  ack {row['ack']}" if row["ack"] else ""
        lines.append(
            f"  {name:<16} requested {row['requested_hz']:6.1f} Hz  achieved {row['achieved_hz']:6.1f} Hz{ack}"
        )
    others = {k: v for k, v in stats["rates_hz"].items() if k not in streams["messages"]}
    if others:
        lines.append("  other: " + ", ".join(f"{k} {v:.1f} Hz" for k, v in others.items()))
    recording = report.get("recording") or {}
    lines.append(
        f"recording  {recording.get('state', 'off')}  {recording.get('folder') or ''}  {recording.get('error') or ''}"
    )
    lines.append("events")
    lines += [f"  {e['kind']}: {e['detail']}" for e in link["events"]]
    return "\n".join(lines)
