"""What the commands share: failing with one line on stderr, and a progress bar for long runs."""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable
from typing import Any

import numpy as np
from tqdm import tqdm

from gcs.core.gains import PresetFile
from gcs.logs.logfile import InputError
from gcs.mavlink.params import float32


def run_reporting_errors(command: str, out: str, work: Callable[[], str], source: str | None = None) -> int:
    """Run work() (it returns what to tell the user); bad input (InputError names file, offset,
    field) or an unwritable output becomes one line on stderr and exit code 2, never a traceback.
    An `out` that is the `source` read (the flight log itself) is refused before anything runs."""
    if source is not None and same_file(source, out):
        print(f"gcs {command}: error: --out {out} is the input itself; give another file", file=sys.stderr)
        return 2
    try:
        done = work()
    except InputError as exc:
        print(f"gcs {command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"gcs {command}: error: {os_error_line(exc, out)}", file=sys.stderr)
        return 2
    print(done, file=sys.stderr)
    return 0


def same_file(source: str, out: str) -> bool:
    """Whether writing `out` would replace the file `source` (the same path, ./x for x, a link):
    `gcs report flight.bin --out flight.bin` replaced the flight log with its report."""
    return os.path.isfile(source) and os.path.isfile(out) and os.path.samefile(source, out)


def os_error_line(exc: OSError, path: str | None = None) -> str:
    """An OSError in one line: the file it names (else `path`) and why, without the "[Errno N]".
    One made from a message alone (FileNotFoundError("DATASET: no flights")) has neither filename
    nor strerror: its message says it all."""
    if not exc.strerror:
        return str(exc)
    where = exc.filename or path
    return f"{where}: {exc.strerror}" if where else exc.strerror


def progress_bar(label: str) -> Callable[[int, int], None]:
    """A progress bar on stderr (tqdm) for long runs, told (done, total); nothing at all when
    stderr is not a terminal (CI logs, pipes). The bar closes when done reaches total."""
    bar: tqdm[None] | None = None

    def show(done: int, total: int) -> None:
        nonlocal bar
        if bar is None:
            bar = tqdm(total=total, desc=label, unit="", disable=not sys.stderr.isatty(), leave=True)
        bar.total = total
        bar.update(done - bar.n)
        if done >= total:
            bar.close()

    return show


def load_preset_file(path: str) -> PresetFile:
    """A preset file (`gcs sweep` writes them); OSError or GainError say what is wrong."""
    with open(path) as fh:
        return PresetFile.from_toml(fh.read(), path)


def tidy(value: Any) -> Any:
    """value with every float shown without binary noise, for what a command prints: a float32
    (0.1f is 0.10000000149 as a double; 0.7f - 0.6f is 0.099999994) as the shortest text within
    one float32 step of it (0.1), any other double to 15 significant digits (49.033249999999995
    → 49.03325). Lists, tuples and dicts are walked; everything else is returned as is."""
    if isinstance(value, float) and math.isfinite(value):
        if float32(value) != value:
            return float(f"{value:.15g}")
        step = abs(float(np.spacing(np.float32(value))))
        for digits in range(1, 10):
            text = f"{value:.{digits}g}"
            if abs(float(text) - value) <= step:
                return float(text)
        return value
    if isinstance(value, dict):
        return {k: tidy(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [tidy(v) for v in value]
    return value
