"""`gcs status`: connect, request streams, and print what a field engineer checks first."""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import math
import sys

from gcs.commands.common import tidy
from gcs.commands.options import add_link_arguments, links_of, station_config_or_report
from gcs.core import strict_json
from gcs.runtime.fleet import Fleet
from gcs.runtime.snapshots import LinkCounters, StationSnapshot
from gcs.runtime.station import StationConfig
from gcs.transport.address import parse_address


def add_arguments(parser: argparse.ArgumentParser) -> None:

    add_link_arguments(parser, record="opt-in", several=True)
    parser.add_argument("--duration", type=float, default=10.0, help="seconds to listen (default 10)")
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def run(args: argparse.Namespace) -> int:
    if not (args.duration > 0 and math.isfinite(args.duration)):  # -5 or nan listened for 0 s
        print(f"gcs status: --duration {args.duration!r}: give seconds > 0", file=sys.stderr)
        return 2
    config = station_config_or_report(args, "status")
    if config is None:
        return 2
    if config.record and any(parse_address(a).kind == "tlog" for a in links_of(args)):
        # the report then said only "recording  off", as if --record had been ignored
        print(
            "gcs status: note: --record: a replayed .tlog is not recorded again (it is the recording)", file=sys.stderr
        )
    snapshots = asyncio.run(_collect(config, links_of(args), args.duration))
    first = snapshots[0]
    if args.json:  # the first vehicle's snapshot, as with one vehicle, and every vehicle's in "vehicles"
        body = tidy(dataclasses.asdict(first))
        body["vehicles"] = [tidy(dataclasses.asdict(s)) for s in snapshots]
        print(strict_json.dumps(body, indent=2))
    elif len(snapshots) == 1:
        print(format_report(first))
    else:
        print(format_vehicles(snapshots))
    return 0 if any(s.vehicle.heartbeats for s in snapshots) else 1


async def _collect(config: StationConfig, connects: list[str], duration: float) -> list[StationSnapshot]:
    """Every vehicle's snapshot after `duration` s (the first vehicle's place even if none is heard)."""
    fleet = Fleet(config, connects)
    await fleet.start()
    try:
        await asyncio.sleep(duration)
    finally:
        snapshots = [entry.station.publish() for entry in fleet.vehicles()]
        await fleet.stop()
    return snapshots


def format_vehicles(snapshots: list[StationSnapshot]) -> str:
    """A line per vehicle, then each vehicle's full report."""
    lines = [f"vehicles   {len(snapshots)}"]
    for snap in snapshots:
        v = snap.vehicle
        lines.append(
            f"  sysid {v.sysid}  {v.autopilot}  {v.vehicle_type}  on {snap.link.address}  {snap.link.state}"
            + (f" ({snap.link.lost_reason})" if snap.link.lost_reason else "")
            + f"  firmware {v.firmware or '?'}"
        )
    for snap in snapshots:
        lines += ["", f"== vehicle sysid {snap.vehicle.sysid} ==", format_report(snap)]
    return "\n".join(lines)


def format_loss(stats: LinkCounters, two_senders: bool) -> str:
    """Packets lost by sequence number: unknown while two senders' numbers interleave (each step
    between them would count as up to 127 lost)."""
    if two_senders:
        return "unknown (two senders' sequence numbers interleave)"
    return f"{stats.packets_lost} ({100 * stats.loss_fraction:.2f} %)"


def format_report(snap: StationSnapshot) -> str:
    link, vehicle, streams, stats, recording = snap.link, snap.vehicle, snap.streams, snap.link.stats, snap.recording
    heard = link.heartbeat_age_s is not None
    lines = [
        f"link       {link.address}  state {link.state}"
        + (f" ({link.lost_reason})" if link.lost_reason else "")
        + (f" ({link.open_error}; retrying)" if link.open_error else "")
        + "  "
        + (f"heartbeat age {link.heartbeat_age_s} s" if heard else "no heartbeat yet"),
        f"vehicle    sysid {vehicle.sysid}  {vehicle.autopilot}  {vehicle.vehicle_type}  "
        f"MAVLink {vehicle.mavlink_version}  {'ARMED' if vehicle.armed else 'disarmed'}  "
        f"firmware {vehicle.firmware or '?'}"
        + ("  TWO VEHICLES SEND AS THIS SYSTEM: give each its own system id" if vehicle.two_senders else "")
        + "".join(
            f"\n           ANOTHER VEHICLE SENDS AS THIS SYSTEM on {other}: not served; give each its own system id"
            for other in vehicle.others
        )
        if vehicle.sysid is not None
        else "vehicle    none heard",
        f"traffic    {stats.packets} packets  {stats.bytes_per_s:.0f} B/s  CRC errors {stats.crc_errors}  "
        f"malformed {stats.malformed}  lost {format_loss(stats, vehicle.two_senders)}  "
        f"kernel drops {stats.kernel_drops}",
        f"streams    via {streams.method or '?'}  ({streams.requests_sent} requests sent)"
        if streams.method is not None or streams.requests_sent
        else "streams    none requested: a replayed file is no vehicle"
        if parse_address(snap.link.address).kind == "tlog"
        else "streams    none requested yet",
    ]
    for name, row in streams.messages.items():
        accepted = "     ?" if row.accepted_hz is None else f"{row.accepted_hz:6.1f}"
        lines.append(
            f"  {name:<16} requested {row.requested_hz:6.1f} Hz  accepted {accepted} Hz  "
            f"achieved {row.achieved_hz:6.1f} Hz  via {row.method or '?'}"
        )
        if row.reason:
            lines.append(f"  {'':<16} {row.reason}")
    lines += format_radio(snap)
    lines += format_outputs(snap)
    others = {k: v for k, v in stats.rates_hz.items() if k not in streams.messages}
    if others:
        lines.append("  other: " + ", ".join(f"{k} {v:.1f} Hz" for k, v in others.items()))
    if link.signing is not None:
        s = link.signing
        refused = ", ".join(f"{why} {n}" for why, n in s.rejected.items()) or "none"
        flagged = ", ".join(f"{why} {n}" for why, n in s.accepted_unsigned.items()) or "none"
        lines.append(
            f"signing    {'required' if s.required else 'optional'}  good {s.good}  refused: {refused}  "
            f"accepted unsigned: {flagged}"
        )
    if stats.nonfinite_rejected:
        lines.append(
            "rejected   non-finite values: " + ", ".join(f"{k} {n}" for k, n in stats.nonfinite_rejected.items())
        )
    lines.append(f"recording  {recording.state}  {recording.folder or ''}  {recording.error or ''}")
    lines += [f"part       {p.name} failed: {p.error}" for p in snap.parts if p.state == "failed"]
    lines.append("events")
    lines += [f"  {e.kind}: {e.detail}" for e in link.events]
    return "\n".join(lines)


def format_outputs(snap: StationSnapshot) -> list[str]:
    """Where `--out` forwarded the packets and how many went each way: the report never said,
    so a ground station fed through one could not be told from one the output never reached
    (a TCP peer not listening is retried, unopened, for the whole run)."""
    return [
        f"forward    {o.address}  {'open' if o.open else 'NOT OPEN (see events)'}  "
        f"{o.packets_out} packets sent, {o.packets_in} received"
        for o in snap.outputs
    ]


def format_radio(snap: StationSnapshot) -> list[str]:
    """The radio's state and each stream's cost against what the link carries (gcs.runtime.radio)."""
    radio = snap.radio
    if radio is None or not radio.present or radio.status is None:
        return []
    s = radio.status
    shared = f", shared by {radio.shared_by} vehicles" if radio.shared_by > 1 else ""
    lines = [
        f"radio      rssi {s.rssi}/{s.remrssi} (remote)  noise {s.noise}/{s.remnoise}  txbuf {s.txbuf} % free  "
        f"rxerrors {s.rxerrors}  fixed {s.fixed}",
        f"  budget   {radio.used_bps:.0f} B/s used of {radio.capacity_bps:.0f} B/s "
        f"(plan {radio.budget_bps:.0f}{shared})  streams at {radio.scale:.0%} of wanted "
        f"(predicted {radio.predicted_scale:.0%}): {radio.choice}",
    ]
    for name, row in radio.streams.items():
        lines.append(
            f"  {name:<16} wanted {row.wanted_hz:5.1f}  predicted {row.predicted_hz:5.1f}  "
            f"requested {row.requested_hz:5.1f}  achieved {row.achieved_hz:5.1f} Hz  {row.cost_bps:6.0f} B/s"
        )
    return lines
