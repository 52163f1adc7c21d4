"""`gcs sim`: run the built-in simulated vehicle on a UDP, TCP or pseudo-terminal link."""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path
from typing import Any

from gcs.mavlink.signing import parse_key
from gcs.sim.ascii import AsciiFirmware
from gcs.sim.radio import fit_radio
from gcs.sim.recording import fly_flight_logs
from gcs.sim.sensors import SensorFaults
from gcs.sim.vehicle import SimVehicle
from gcs.transport.address import parse_address

PROFILES = ("apm25", "pixhawk", "px4")
SCRIPTS = ("bench", "circuit", "quad")

_EPILOG = """\
links:
  udpout:HOST:PORT   send to a ground station listening there (default udpout:127.0.0.1:14550)
  udpin:HOST:PORT    listen for UDP; replies go to the last sender
  tcpin:HOST:PORT    listen for one TCP ground station (e.g. tcpin:127.0.0.1:5760)
  tcp:HOST:PORT      dial a TCP server
  pty:PATH           a pseudo-terminal serial port whose slave appears as a symlink at PATH
                     (one a killed sim left is replaced; a live one or a file is refused)

profiles:
  apm25    ArduCopter 3.2.1 on APM 2.5: MAVLink 1, all streams off until REQUEST_DATA_STREAM
  pixhawk  ArduCopter 4.x: MAVLink 2, REQUEST_DATA_STREAM and SET_MESSAGE_INTERVAL (<= 320 Hz)
  px4      PX4: MAVLink 2, default streams, SET_MESSAGE_INTERVAL, bytewise integer parameters

scripts:
  bench    seed 000 bench tests: roll -30/-45/-60, pitch 30/45/60, yaw -30/-45/+60, held and undone
  circuit  seed 000 ground-vehicle circuit: a car on a rounded rectangle with roll/pitch zones
  quad     quadcopter: take-off, coordinated 8 m/s circles, landing

faults (--fault NAME=VALUE, repeatable):
  sensor errors, see gcs.sim.sensors.SensorFaults: gyro_noise rad/s, gyro_bias rad/s,
    gyro_bias_walk rad/s/sqrt(s), accel_noise m/s2, vibration m/s2, vibration_freq Hz,
    mag_noise gauss, mag_hard_iron X,Y,Z gauss, declination rad (default: the World
    Magnetic Model's at home), inclination rad,
    field_strength gauss, baro_noise Pa, gps_pos_noise m, gps_vel_noise m/s
  perfect=1                 all sensor errors zero (then other --fault values apply)
  param_drop=FRACTION       drop that fraction of PARAM_VALUE packets
  param_clamp.NAME=MAX      store at most MAX for parameter NAME (tests set-and-verify)
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = _EPILOG
    parser.add_argument("--profile", choices=PROFILES, default="pixhawk", help="autopilot behaviour (default pixhawk)")
    parser.add_argument("--script", choices=SCRIPTS, default="bench", help="truth motion (default bench)")
    parser.add_argument(
        "--link",
        default="udpout:127.0.0.1:14550",
        metavar="ADDRESS",
        help="where to serve the vehicle (default udpout:127.0.0.1:14550)",
    )
    parser.add_argument("--speed", type=float, default=1.0, help="vehicle clock rate vs. wall clock (default 1)")
    parser.add_argument("--seed", type=int, default=0, help="noise seed; same seed, same bytes (default 0)")
    parser.add_argument("--sysid", type=int, default=1, help="MAVLink system id (default 1)")
    parser.add_argument(
        "--no-declination-param",
        action="store_true",
        help="the vehicle has no COMPASS_DEC / EKF2_MAG_DECL parameter (the ground station must use the WMM)",
    )
    parser.add_argument(
        "--ascii",
        action="store_true",
        help="run seed 000's firmware: plain `pitch,yaw,roll` lines (degrees) instead of MAVLink",
    )
    parser.add_argument("--ascii-rate", type=float, default=10.0, help="lines per second with --ascii (default 10)")
    parser.add_argument(
        "--ascii-malformed", type=float, default=0.0, help="fraction of damaged lines with --ascii (default 0)"
    )
    parser.add_argument(
        "--radio",
        type=int,
        metavar="BAUD",
        help="a 3DR/SiK radio of that baud (e.g. 57600) between vehicle and station: limited bandwidth, RADIO_STATUS",
    )
    parser.add_argument(
        "--flight-log",
        type=float,
        action="append",
        default=[],
        metavar="SECONDS",
        help="an earlier flight of that length, flown at start: its onboard log is log 1, 2, ... (repeatable)",
    )
    parser.add_argument(
        "--log-drop", type=float, default=0.0, metavar="FRACTION", help="lose that fraction of LOG_DATA packets"
    )
    parser.add_argument(
        "--log-dir", metavar="DIR", help="also write each finished onboard log there (00000001.BIN, ...)"
    )
    parser.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="sensor or parameter-protocol fault, repeatable (see below)",
    )
    parser.add_argument(
        "--max-rate",
        action="append",
        default=[],
        metavar="MESSAGE=HZ",
        help="refuse SET_MESSAGE_INTERVAL faster than HZ for MESSAGE as ArduPlane does (e.g. RAW_IMU=40), repeatable",
    )
    parser.add_argument(
        "--signing-key",
        metavar="PASSPHRASE|FILE",
        help="sign MAVLink 2 with this key and refuse unsigned packets (a key file or a passphrase)",
    )


def parse_max_rates(items: list[str]) -> dict[str, float]:
    """--max-rate MESSAGE=HZ items → {MESSAGE: HZ}; ValueError names the bad one."""
    limits = {}
    for item in items:
        name, _, text = item.partition("=")
        try:
            limits[name.strip().upper()] = float(text)
        except ValueError:
            raise ValueError(f"--max-rate {item!r}: expected MESSAGE=HZ") from None
    return limits


def parse_faults(items: list[str]):
    """--fault NAME=VALUE items → (SensorFaults, param_drop, param_clamp); ValueError names the bad one."""

    sensor: dict[str, Any] = {}  # float or (x, y, z) per SensorFaults field
    perfect, drop, clamp = False, 0.0, {}
    for item in items:
        name, sep, text = item.partition("=")
        name = name.strip()
        try:
            if not sep:
                raise ValueError("expected NAME=VALUE")
            if name == "perfect":
                perfect = text.strip() not in ("0", "false", "no")
            elif name == "param_drop":
                drop = float(text)
                if not 0.0 <= drop <= 1.0:
                    raise ValueError("must be between 0 and 1")
            elif name.startswith("param_clamp."):
                clamp[name.split(".", 1)[1]] = float(text)
            elif name == "mag_hard_iron":
                values = tuple(float(v) for v in text.split(","))
                if len(values) != 3:
                    raise ValueError("needs X,Y,Z")
                sensor[name] = values
            elif name in SensorFaults.names():
                sensor[name] = float(text)
            else:
                raise ValueError("unknown fault name")
        except ValueError as exc:
            raise ValueError(f"--fault {item!r}: {exc}") from None
    faults = SensorFaults.perfect(**sensor) if perfect else SensorFaults(**sensor)
    return faults, drop, clamp


def run(args: argparse.Namespace) -> int:

    try:
        faults, drop, clamp = parse_faults(args.fault)
        limits = parse_max_rates(args.max_rate)
        key = None if args.signing_key is None else parse_key(args.signing_key)
        if args.radio is not None and not 1200 <= args.radio <= 2_000_000:
            raise ValueError("--radio: a baud rate such as 57600")
        if not 0.0 <= args.log_drop < 1.0:
            raise ValueError("--log-drop: a fraction at least 0 and below 1")
        if any(not 0 < seconds <= 3600 for seconds in args.flight_log):
            raise ValueError("--flight-log: a flight lasts more than 0 and at most 3600 s")
        if parse_address(args.link).kind not in ("udpin", "udpout", "tcp", "tcpin", "pty"):
            raise ValueError(f"--link {args.link!r}: the vehicle serves udpout:, udpin:, tcp:, tcpin: or pty:")
    except ValueError as exc:  # AddressError is a ValueError
        print(f"gcs sim: {exc}", file=sys.stderr)
        return 2
    sim = SimVehicle(
        profile=args.profile,
        script=args.script,
        seed=args.seed,
        faults=faults,
        speed=args.speed,
        sysid=args.sysid,
        param_drop=drop,
        param_clamp=clamp,
        publish_declination=not args.no_declination_param,
        interval_limits=limits,
        signing_key=key,
    )
    sim.log_server.drop = args.log_drop
    if args.log_dir:
        sim.logs.log_dir = Path(args.log_dir)
    fly_flight_logs(sim, args.flight_log)
    if args.radio is not None:
        fit_radio(sim, args.radio, seed=args.seed)

    firmware = None
    if args.ascii:
        try:
            firmware = AsciiFirmware(sim, rate_hz=args.ascii_rate, malformed=args.ascii_malformed)
        except ValueError as exc:
            print(f"gcs sim: --ascii-malformed: {exc}", file=sys.stderr)
            return 2

    def serving() -> None:
        speaking = "seed 000's ASCII lines" if firmware else f"sysid {args.sysid}"
        print(
            f"gcs sim: {args.profile} vehicle ({speaking}) flying the {args.script} script "
            f"at {args.speed:g}x on {args.link} (Ctrl-C stops)",
            flush=True,
        )

    try:
        asyncio.run((firmware or sim).run(args.link, on_open=serving))
    except KeyboardInterrupt:
        pass
    except OSError as exc:
        print(f"gcs sim: cannot serve {args.link}: {exc}", file=sys.stderr)
        return 1
    return 0
