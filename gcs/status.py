"""`gcs status`: connect, request streams, and print what a field engineer checks first."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys


def add_link_arguments(parser: argparse.ArgumentParser) -> None:
    """The connection options every live command shares."""
    parser.add_argument("--connect", required=True, metavar="URL",
                        help="udpin:0.0.0.0:14550, udpout:HOST:PORT, tcp:HOST:PORT, tcpin:0.0.0.0:5760, "
                             "a serial device, or a .tlog to replay")
    parser.add_argument("--baud", default="57600", help="serial baud rate, or 'auto' (default 57600)")
    parser.add_argument("--speed", type=float, default=1.0, help="replay speed for a .tlog (0 = as fast as possible)")
    parser.add_argument("--out", action="append", default=[], metavar="URL",
                        help="forward every vehicle packet to this address and back (repeatable)")
    parser.add_argument("--heartbeat-timeout", type=float, default=3.0, help="seconds without heartbeat before 'lost'")
    parser.add_argument("--imu-rate", type=float, default=50.0, help="raw IMU rate to request, Hz (default 50)")
    parser.add_argument("--attitude-rate", type=float, default=50.0, help="ATTITUDE rate to request, Hz (default 50)")
    parser.add_argument("--gps-rate", type=float, default=5.0, help="GPS rate to request, Hz (default 5)")
    parser.add_argument("--record-dir", default="sessions", metavar="DIR",
                        help="record every session to a folder under DIR (default ./sessions)")
    parser.add_argument("--no-record", action="store_true", help="do not record this session")


def station_config(args: argparse.Namespace):
    """The StationConfig the link options ask for; AddressError/ValueError for bad options."""
    from gcs.link.address import parse_address
    from gcs.station import StationConfig
    from gcs.vehicle.streams import StreamPlan

    for address in (args.connect, *args.out):
        parse_address(address)
    if args.baud != "auto" and not args.baud.isdigit():
        raise ValueError(f"--baud {args.baud!r}: give a rate such as 57600, or 'auto'")
    baud = args.baud if args.baud == "auto" else int(args.baud)
    return StationConfig(
        connect=args.connect, baud=baud, speed=args.speed, outputs=args.out,
        heartbeat_timeout=args.heartbeat_timeout,
        plan=StreamPlan(imu_hz=args.imu_rate, attitude_hz=args.attitude_rate, gps_hz=args.gps_rate),
        record_dir=None if args.no_record else args.record_dir,
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_link_arguments(parser)
    parser.add_argument("--duration", type=float, default=10.0, help="seconds to listen (default 10)")
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def run(args: argparse.Namespace) -> int:
    from gcs.link.address import AddressError

    try:
        config = station_config(args)
    except (AddressError, ValueError) as exc:
        print(f"gcs status: {exc}", file=sys.stderr)
        return 2
    report = asyncio.run(_collect(config, args.duration))
    if args.json:
        json.dump(report, sys.stdout, indent=2)
        print()
    else:
        print(format_report(report))
    return 0 if report["vehicle"]["heartbeats"] else 1


async def _collect(config, duration: float) -> dict:
    from gcs.station import GroundStation

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
        lines.append(f"  {name:<16} requested {row['requested_hz']:6.1f} Hz  achieved {row['achieved_hz']:6.1f} Hz{ack}")
    others = {k: v for k, v in stats["rates_hz"].items() if k not in streams["messages"]}
    if others:
        lines.append("  other: " + ", ".join(f"{k} {v:.1f} Hz" for k, v in others.items()))
    recording = report.get("recording") or {}
    lines.append(f"recording  {recording.get('state', 'off')}  {recording.get('folder') or ''}  {recording.get('error') or ''}")
    lines.append("events")
    lines += [f"  {e['kind']}: {e['detail']}" for e in link["events"]]
    return "\n".join(lines)
