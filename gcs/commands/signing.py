"""`gcs signing setup`: give a vehicle its MAVLink 2 signing key (SETUP_SIGNING), as MAVProxy's
`signing setup` does, over a link the vehicle still accepts unsigned packets on (USB, or a
secure link); then check that the vehicle signs its heartbeats with that key.

`--signing-key` is the new key (a key file or a passphrase); `--disable` sends the all-zero key
with a zero timestamp, which switches signing off (SETUP_SIGNING's definition; ArduPilot signs
with a zero key sent with any other timestamp). Later sessions pass the same `--signing-key` to
every command."""

from __future__ import annotations

import argparse
import asyncio
import sys
import time

from gcs.commands.options import add_link_arguments, station_config
from gcs.commands.vehicle_choice import add_sysid_argument, not_heard, one_vehicle
from gcs.mavlink.signing import KEY_BYTES, Signing, setup_signing_message
from gcs.runtime.station import StationConfig

#: SETUP_SIGNING is not acknowledged: it is sent this many times, a little apart (a lost packet).
SENDS = 3


def add_arguments(parser: argparse.ArgumentParser) -> None:
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    setup = actions.add_parser(
        "setup",
        help="send SETUP_SIGNING with --signing-key (or --disable) to the vehicle",
        description="send SETUP_SIGNING with --signing-key (or --disable) to the vehicle",
    )
    add_link_arguments(setup, streams=False, record="never")
    add_sysid_argument(setup)
    setup.add_argument(
        "--disable", action="store_true", help="send the all-zero key and timestamp: the vehicle stops signing"
    )
    setup.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the vehicle (default 10)")


def run(args: argparse.Namespace) -> int:
    try:
        config = station_config(args)
    except ValueError as exc:
        print(f"gcs signing {args.action}: {exc}", file=sys.stderr)
        return 2
    key = bytes(KEY_BYTES) if args.disable else config.signing_key
    if key is None:
        print("gcs signing setup: give the key with --signing-key (or --disable)", file=sys.stderr)
        return 2
    # The vehicle does not know the key yet: the link itself is unsigned.
    config.signing_key, config.request_streams, config.estimate, config.record = None, False, False, False
    done, message = asyncio.run(_setup(config, args.sysid, key, args.timeout, disable=args.disable))
    print(message if done else f"gcs signing setup: {message}", file=sys.stdout if done else sys.stderr)
    return 0 if done else 1


async def _setup(
    config: StationConfig, sysid: int | None, key: bytes, timeout: float, disable: bool
) -> tuple[bool, str]:
    """(done, what happened)."""
    async with one_vehicle(config, sysid) as (fleet, station):
        link = station.link
        if not await link.wait_connected(timeout):
            return False, not_heard(fleet, timeout)
        sysid, compid = link.target_system or 1, link.target_component or 1
        if link.vehicle_mavlink == 1:
            return False, f"vehicle {sysid} speaks only MAVLink 1 (an APM 2.5?): signing needs MAVLink 2; nothing sent"
        beats = link.bus.subscribe("signing-setup", types=["HEARTBEAT"], maxlen=100)
        try:
            for _ in range(SENDS):
                link.send(setup_signing_message(key, sysid, compid, initial_timestamp=0 if disable else None))
                await asyncio.sleep(0.2)
            return await _verify(beats, sysid, Signing(key), timeout, disable)
        finally:
            beats.close()


async def _verify(beats, sysid: int, signing: Signing, timeout: float, disable: bool) -> tuple[bool, str]:
    """The vehicle's next heartbeats signed with the key (or, with --disable, unsigned)."""
    beats.drain()
    deadline = time.monotonic() + timeout
    while (item := await beats.get(timeout=max(deadline - time.monotonic(), 0.0))) is not None:
        if item.sysid != sysid:
            continue
        verdict = signing.check(item.raw, item.type)
        if disable and verdict == "unsigned":
            return True, f"vehicle {sysid}: signing switched off (its heartbeats are unsigned)"
        if not disable and verdict is None:
            return True, f"vehicle {sysid}: signing set up; its heartbeats are signed with this key"
    what = "unsigned heartbeat" if disable else "heartbeat signed with this key"
    return False, f"vehicle {sysid} sent no {what} within {timeout:g} s after SETUP_SIGNING (not accepted?)"
