"""The `gcs` command. Each subcommand lives in the module that owns its feature and exposes
`add_arguments(parser)` and `run(args) -> int`; this file only lists them."""

from __future__ import annotations

import argparse
import importlib
import os
import select
import signal
import sys
from collections.abc import Collection

from gcs.provenance import provenance

#: subcommand -> (module, one-line help). A command's module is imported only when that command is
#: asked for: `gcs replay` does not pay for the server's imports (FastAPI, viser, uvicorn: ~1 s).
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("gcs.commands.demo", "start the simulated vehicle and the ground station together (no hardware needed)"),
    "status": (
        "gcs.commands.status",
        "connect to a vehicle and print link health, rates requested vs achieved (records only with --record)",
    ),
    "sim": ("gcs.commands.sim", "run the built-in simulated vehicle over UDP, TCP or a serial pseudo-terminal"),
    "estimate": (
        "gcs.commands.estimate",
        "run an attitude estimator over a .tlog, DataFlash .bin or text .log, PX4 .ulg or CSV and write its output CSV",
    ),
    "serve": (
        "gcs.commands.serve",
        "connect to a vehicle and serve the browser dashboard (plots, 3-D view, gain sliders)",
    ),
    "sessions": ("gcs.commands.sessions", "list recorded sessions with start, duration, size and vehicle"),
    "replay": (
        "gcs.commands.replay",
        "replay a session, .tlog, .bin, .log or .ulg through the estimators (play at any speed)",
    ),
    "export": (
        "gcs.commands.export",
        "export the attitude of every source (onboard, references, estimators) of a session or log as CSV, "
        "Parquet, MAT or MCAP",
    ),
    "report": ("gcs.commands.report", "write a self-contained HTML flight-test report of a session or log"),
    "batch": (
        "gcs.commands.batch",
        "every log or session of a fleet through the estimators into a Parquet dataset (Dask)",
    ),
    "sweep": ("gcs.commands.sweep", "search estimator gains over many flights (Dask tasks) and write a preset file"),
    "fleet": ("gcs.commands.fleet", "fleet datasets: `gcs fleet report DATASET --out FILE.html`"),
    "params": (
        "gcs.commands.params",
        "read, write (verified), save, load and diff the vehicle's parameters (records only with --record)",
    ),
    "signing": ("gcs.commands.signing", "MAVLink 2 signing: `gcs signing setup` sends the vehicle its key"),
    "logs": ("gcs.commands.logs", "list and download the vehicle's onboard DataFlash logs (resumable)"),
    "protocol": (
        "gcs.commands.protocol",
        "run a guided bench-test protocol (prompts, hold detection, the seeds' error figures) or report one",
    ),
}


def build_parser(commands: Collection[str] | None = None) -> argparse.ArgumentParser:
    """The whole command line; with `commands`, only those commands' options (the others are
    listed with their help, so `gcs --help` and a mistyped command read as before)."""
    parser = argparse.ArgumentParser(
        prog="gcs",
        description="MAVLink ground station and telemetry server for flight tests.",
    )
    parser.add_argument("--version", action="version", version=str(provenance()))
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=module)
        if commands is None or name in commands:
            importlib.import_module(module).add_arguments(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    command = next((arg for arg in argv if not arg.startswith("-")), None)
    parser = build_parser(() if command is None else (command,))
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    terminated = stop_on_sigterm()
    try:
        code = int(importlib.import_module(args._module).run(args) or 0)
        sys.stdout.flush()  # here, not at exit: a reader gone is then caught below
        return code
    except KeyboardInterrupt:
        return 143 if terminated else 130
    except BrokenPipeError:
        if not stdout_reader_gone():
            raise  # a socket's or another pipe's: a real error, with its traceback
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # nothing more to flush at exit
        return 128 + signal.SIGPIPE


def stdout_reader_gone() -> bool:
    """Whether whatever read stdout has closed it (`gcs sessions --json | head`): the pipe's
    write end then polls as an error. A command piped into `head` stops quietly, as a C tool
    killed by SIGPIPE does (exit 141), where Python printed a BrokenPipeError traceback."""
    poll = select.poll()
    poll.register(sys.stdout.fileno(), select.POLLOUT)
    return any(events & select.POLLERR for _, events in poll.poll(0))


def stop_on_sigterm() -> list[int]:
    """SIGTERM (systemd, docker, kill) stops a command as Ctrl-C does: it becomes SIGINT, which
    asyncio turns into a cancellation of the main task, so every `finally` runs (the session is
    closed, its files completed). A process started with SIGINT ignored (`cmd &` in a script, a
    supervisor that ignores it) gets Python's own SIGINT handler back, or SIGTERM would be lost and
    the process could only be killed. The returned list gets the signal number once it arrived."""
    received: list[int] = []
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)

    def interrupt(signum: int, frame: object) -> None:
        received.append(signum)
        signal.raise_signal(signal.SIGINT)

    signal.signal(signal.SIGTERM, interrupt)
    return received


if __name__ == "__main__":
    sys.exit(main())
