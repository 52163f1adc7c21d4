"""What the commands share: failing with one line on stderr, and a progress bar for long runs."""

from __future__ import annotations

import sys
from collections.abc import Callable

from gcs.logs.logfile import InputError


def run_reporting_errors(command: str, out: str, work: Callable[[], str]) -> int:
    """Run work() (it returns what to tell the user); bad input (InputError names file, offset,
    field) or an unwritable output becomes one line on stderr and exit code 2, never a traceback."""
    try:
        done = work()
    except InputError as exc:
        print(f"gcs {command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"gcs {command}: error: {exc.filename or out}: {exc.strerror}", file=sys.stderr)
        return 2
    print(done, file=sys.stderr)
    return 0


def progress_bar(label: str) -> Callable[[int, int], None]:
    """A one-line progress bar on stderr for long runs."""

    def show(done: int, total: int) -> None:
        width = 30
        filled = int(width * done / max(total, 1))
        end = "\n" if done >= total else ""
        print(
            f"\r{label} [{'#' * filled}{'.' * (width - filled)}] {100 * done / max(total, 1):5.1f} %",
            end=end,
            file=sys.stderr,
            flush=True,
        )

    return show
