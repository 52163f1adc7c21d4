"""What the commands share: failing with one line on stderr, and a progress bar for long runs."""

from __future__ import annotations

import sys
from collections.abc import Callable

from tqdm import tqdm

from gcs.core.gains import PresetFile
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
