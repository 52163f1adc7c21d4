"""`--sysid N`: which vehicle a one-vehicle command (params, logs, signing, protocol) addresses
on a link several vehicles share (a MAVLink router, a mesh radio, `gcs serve --out`). Without it
the command takes the first vehicle heard, as it always did; every other vehicle is ignored
(gcs.runtime.fleet, `single`)."""

from __future__ import annotations

import argparse
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from gcs.runtime.fleet import Fleet
from gcs.runtime.station import Station, StationConfig


def add_sysid_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--sysid",
        type=sysid_value,
        default=None,
        metavar="N",
        help="the vehicle to address when several share the link (default: the first heard)",
    )


def sysid_value(text: str) -> int:
    if not text.isdigit() or not 1 <= int(text) <= 255:
        raise argparse.ArgumentTypeError(f"{text!r}: a system id is 1 to 255")
    return int(text)


@asynccontextmanager
async def one_vehicle(config: StationConfig, sysid: int | None) -> AsyncIterator[tuple[Fleet, Station]]:
    """A fleet of that one vehicle, started, and its core; stopped on the way out."""
    fleet = Fleet(config, single=True, sysid=sysid)
    await fleet.start()
    try:
        yield fleet, fleet.first
    finally:
        await fleet.stop()


def not_heard(fleet: Fleet, timeout: float) -> str:
    """The one line for a vehicle that did not answer in time (naming the vehicles that did)."""
    where = fleet.config.connect
    if fleet.sysid is None:
        return f"no heartbeat from a vehicle on {where} within {timeout:g} s"
    heard = ", ".join(str(n) for n in sorted(fleet.heard)) or "none"
    return f"no heartbeat from vehicle sysid {fleet.sysid} on {where} within {timeout:g} s (vehicles heard: {heard})"
