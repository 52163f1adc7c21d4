"""Command-line options shared by every command that opens a live link (`status`, `serve`,
`params`) or records (`demo`), so each option is defined, documented and validated once."""

from __future__ import annotations

import argparse
import errno
import math
import os
import sys

from gcs.mavlink.ascii import UNITS, AsciiFormat
from gcs.mavlink.signing import parse_key
from gcs.runtime.station import StationConfig
from gcs.runtime.streams import StreamPlan
from gcs.transport.address import AddressError, parse_address
from gcs.transport.pipes import probe_serial


def add_link_arguments(
    parser: argparse.ArgumentParser,
    connect_required: bool = True,
    *,
    streams: bool = True,
    record: str = "default",
    several: bool = False,
    forward: bool = True,
) -> None:
    """--connect and the link and forwarding options; with `streams`, the stream-rate, replay
    speed and ascii-line options (what the estimators need); `record`: "default" records unless
    --no-record (serve, protocol), "opt-in" only with --record (status, params: a quick look
    leaves no session folder behind), "never" no recording options (signing setup, logs record
    nothing); `several`: --connect repeatable (a fleet: serve, status); without `forward`, no
    --out (logs download's --out is its folder)."""
    parser.add_argument(
        "--connect",
        required=connect_required,
        action="append" if several else "store",
        metavar="URL",
        help="udpin:0.0.0.0:14550, udpout:HOST:PORT, tcp:HOST:PORT, tcpin:0.0.0.0:5760, "
        "a serial device, or a .tlog to replay"
        + ("; ascii:ADDRESS for text attitude lines (seed 000's firmware)" if streams else "")
        + ("; repeatable: every vehicle heard on every link is served" if several else ""),
    )
    parser.add_argument("--baud", default="57600", help="serial baud rate, or 'auto' (default 57600)")
    if forward:
        parser.add_argument(
            "--out",
            action="append",
            default=[],
            metavar="URL",
            help="forward every vehicle packet to this address and back (repeatable)",
        )
    parser.add_argument("--heartbeat-timeout", type=float, default=3.0, help="seconds without heartbeat before 'lost'")
    if streams:
        parser.add_argument(
            "--speed", type=float, default=1.0, help="replay speed for a .tlog (0 = as fast as possible)"
        )
        parser.add_argument("--imu-rate", type=float, default=50.0, help="raw IMU rate to request, Hz (default 50)")
        parser.add_argument(
            "--attitude-rate", type=float, default=50.0, help="ATTITUDE rate to request, Hz (default 50)"
        )
        parser.add_argument("--gps-rate", type=float, default=5.0, help="GPS rate to request, Hz (default 5)")
        parser.add_argument(
            "--ascii-fields",
            default="pitch,yaw,roll",
            metavar="A,B,C",
            help="column order of an ascii: link's lines, - for a column to ignore (default seed 000's pitch,yaw,roll)",
        )
        parser.add_argument(
            "--ascii-unit", choices=UNITS, default="deg", help="angle unit of an ascii: link (default deg)"
        )
    add_signing_arguments(parser)
    if record != "never":
        add_record_arguments(parser, opt_in=record == "opt-in")


def add_signing_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--signing-key",
        metavar="PASSPHRASE|FILE",
        help="sign MAVLink 2 with this key: a key file (32 bytes or 64 hex digits) or a passphrase (SHA-256)",
    )
    parser.add_argument(
        "--signing",
        choices=("required", "optional"),
        default="required",
        help="with --signing-key: refuse unsigned packets (required, default) or accept and count them",
    )


def signing_key(args: argparse.Namespace) -> bytes | None:
    """The key --signing-key names, None without it; SigningKeyError (a ValueError) if unusable."""
    value = getattr(args, "signing_key", None)
    return None if value is None else parse_key(value)


def add_record_arguments(parser: argparse.ArgumentParser, opt_in: bool = False) -> None:
    """--record-dir and --no-record, or (opt_in) --record and --record-dir."""
    if opt_in:
        parser.add_argument("--record", action="store_true", help="record this session (default: not recorded)")
        parser.add_argument(
            "--record-dir", default="sessions", metavar="DIR", help="with --record: the folder (default ./sessions)"
        )
        return
    parser.add_argument(
        "--record-dir",
        default="sessions",
        metavar="DIR",
        help="record every session to a folder under DIR (default ./sessions); the dashboard's sessions, replay "
        "and what-if lists read DIR, with --no-record too",
    )
    parser.add_argument("--no-record", action="store_true", help="do not record this session")


def recording(args: argparse.Namespace) -> bool:
    """Whether to record: not with --no-record, for an opt-in command without --record, or for a
    command that never records."""
    return hasattr(args, "record_dir") and not getattr(args, "no_record", False) and getattr(args, "record", True)


def station_config(args: argparse.Namespace):
    """The StationConfig the link options ask for; AddressError/ValueError for bad options,
    OSError (one line) for a serial port that cannot be opened now."""

    connects = links_of(args)
    outputs: list[str] = getattr(args, "out", [])  # none without the forwarding option (forward=False)
    addresses = [parse_address(address) for address in (*connects, *outputs)]
    if args.baud != "auto" and not args.baud.isdigit():
        raise ValueError(f"--baud {args.baud!r}: give a rate such as 57600, or 'auto'")
    baud = args.baud if args.baud == "auto" else int(args.baud)
    if baud == 0:  # termios' B0 hangs the line up (drops DTR: an APM 2.5 on USB resets), never a rate
        raise ValueError("--baud 0: give a rate such as 57600, or 'auto' (0 would hang up the serial line)")
    check_numbers(args)
    for address in addresses:
        if address.kind == "serial" and os.path.isfile(address.path):  # a log given as a link
            raise ValueError(
                f"{address.path}: a file, not a serial device: only a .tlog is replayed as a link; "
                f"`gcs replay {address.path}` replays a .bin, .log or .ulg"
            )
        if address.kind == "serial" and address.path:
            probe_serial(address.path, 57600 if baud == "auto" else baud)
        if address.kind == "tlog" and not os.path.isfile(address.path):  # a replay never reappears: no retrying
            raise OSError(errno.ENOENT, f"{address.path}: no such file")
    config = StationConfig(
        connect=connects[0],
        baud=baud,
        outputs=outputs,
        heartbeat_timeout=args.heartbeat_timeout,
        sessions_dir=getattr(args, "record_dir", "sessions"),
        record=recording(args),
        signing_key=signing_key(args),
        signing_required=args.signing == "required",
    )
    if hasattr(args, "imu_rate"):  # the stream options (add_link_arguments(streams=True))
        config.speed = args.speed
        config.plan = StreamPlan(imu_hz=args.imu_rate, attitude_hz=args.attitude_rate, gps_hz=args.gps_rate)
        config.ascii_format = AsciiFormat.parse(args.ascii_fields, args.ascii_unit)
    return config


def check_speed(speed: float) -> None:
    """A replay speed, or ValueError: argparse's float takes -1, nan and inf."""
    if not (speed >= 0 and math.isfinite(speed)):
        raise ValueError(f"--speed {speed!r}: give a number >= 0 (0 = as fast as possible)")


def check_numbers(args: argparse.Namespace) -> None:
    """The link options' numbers, or ValueError naming the option: a negative or NaN rate would
    ask the vehicle to stop the stream, a timeout of 0 call every link lost."""
    if not (args.heartbeat_timeout > 0 and math.isfinite(args.heartbeat_timeout)):
        raise ValueError(f"--heartbeat-timeout {args.heartbeat_timeout!r}: give seconds > 0")
    if not hasattr(args, "imu_rate"):  # no stream options (add_link_arguments(streams=False))
        return
    check_speed(args.speed)
    for option, hz in (
        ("--imu-rate", args.imu_rate),
        ("--attitude-rate", args.attitude_rate),
        ("--gps-rate", args.gps_rate),
    ):
        if not (hz >= 0 and math.isfinite(hz)):
            raise ValueError(f"{option} {hz!r}: give a rate >= 0 Hz (0 = off)")


def links_of(args: argparse.Namespace) -> list[str]:
    """Every --connect address, in order (one, or several where --connect repeats)."""
    connect = args.connect
    return list(connect) if isinstance(connect, list) else [connect]


def station_config_or_report(args: argparse.Namespace, command: str):
    """station_config(args), or None after printing `gcs COMMAND: what is wrong` to stderr."""

    try:
        return station_config(args)
    except (AddressError, ValueError) as exc:
        print(f"gcs {command}: {exc}", file=sys.stderr)
        return None
    except OSError as exc:
        print(f"gcs {command}: error: {exc.strerror or exc}", file=sys.stderr)
        return None
