"""`gcs sessions`: the recorded sessions, oldest first. Nothing is ever deleted by gcs; sessions
a crash left open are shown as such (the next `gcs status`/server start recovers them), and one
whose meta.json cannot be read as damaged, with why (no recovery mends that)."""

from __future__ import annotations

import argparse
import os
import sys
import time

from gcs.core import strict_json
from gcs.sessions.layout import list_sessions


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--dir", default="sessions", help="recording folder (default ./sessions)")
    parser.add_argument("--json", action="store_true", help="print a JSON list")


def format_size(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n} B"


def format_table(sessions) -> str:
    lines = [f"{'session':<48}{'start':<21}{'duration':>10}{'size':>11}  {'vehicle':<24}state"]
    for s in sessions:
        start = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(s.start)) if s.start else "?"
        duration = f"{s.duration_s:.1f} s" if s.duration_s is not None else "-"
        state = (
            f"damaged: {s.error}"
            if s.error
            else "open (recording, or left by a crash)"
            if s.open
            else ("recovered" if s.recovered else "closed")
        )
        lines.append(
            f"{s.name:<48}{start:<21}{duration:>10}{format_size(s.size_bytes):>11}  {s.vehicle or '?':<24}{state}"
        )
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:

    if args.dir != "sessions" and not os.path.isdir(args.dir):  # a typo, not a station that never recorded
        what = "no such folder" if not os.path.exists(args.dir) else "not a folder"
        print(f"gcs sessions: error: {args.dir}: {what}", file=sys.stderr)
        return 2
    sessions = list_sessions(args.dir)
    if args.json:
        print(strict_json.dumps([s.as_dict() for s in sessions], indent=2))
    elif sessions:
        print(format_table(sessions))
    else:
        print(f"no sessions in {args.dir}", file=sys.stderr)
    return 0
