"""How the session commands (`gcs export`, `gcs report`) fail: one line on stderr, exit code 2."""

from __future__ import annotations

import sys
from typing import Callable


def run_reporting_errors(command: str, out: str, work: Callable[[], str]) -> int:
    """Run work() (it returns what to tell the user); bad input (InputError names file, offset,
    field) or an unwritable output becomes one line on stderr and exit code 2, never a traceback."""
    from gcs.sessions.readers import InputError

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
