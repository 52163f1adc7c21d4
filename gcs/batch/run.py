"""`gcs batch`: every flight given through the estimators into a dataset, one task per flight.

Flights already in the dataset are skipped unless `force`; each task reads, replays and writes
one flight and returns a `FlightResult`, so the driver's memory does not grow with the fleet.
"""

from __future__ import annotations

import glob
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from distributed import Client

from gcs.batch import dataset
from gcs.batch.cluster import completed
from gcs.batch.flight import FlightResult, process_flight
from gcs.sessions import layout
from gcs.sessions.sources import KINDS


def find_flights(items: Iterable[str]) -> tuple[list[str], list[str]]:
    """Files, session folders, folders of them and globs → the flights, each once, in order, and
    the items that gave none (a glob matching nothing, a folder with no session or log: an SD card
    not mounted, a mistyped folder), for the command to name: they were dropped without a word and
    the dataset silently lacked a day of flights. A folder that is not a session contributes its
    sessions and logs (not recursively); anything else named is kept, so that a file that cannot be
    read is reported, not silently dropped."""
    found: list[str] = []
    empty: list[str] = []
    for item in items:
        matches = sorted(glob.glob(item)) if glob.has_magic(item) else [item]
        before = len(found)
        for path in matches:
            folder = Path(path)
            if folder.is_dir() and not layout.is_session(folder):
                found += [
                    str(p)
                    for p in sorted(folder.iterdir())
                    if layout.is_session(p) or (p.is_file() and p.suffix.lower() in KINDS)
                ]
            else:
                found.append(path)
        if len(found) == before:
            empty.append(item)
    return list(dict.fromkeys(found)), empty


def no_flight_lines(command: str, empty: list[str]) -> list[str]:
    """One stderr line per item that gave no flight (find_flights)."""
    kinds = ", ".join(KINDS)
    return [
        f"gcs {command}: warning: {item}: "
        + (
            "matches no file"
            if glob.has_magic(item) and not glob.glob(item)
            else f"no session folder or {kinds} file there"
        )
        for item in empty
    ]


@dataclass(frozen=True)
class BatchOutcome:
    done: list[FlightResult]  # processed now (good and failed)
    skipped: list[str]  # already in the dataset
    removed: list[str]  # temporary folders of writers killed mid-flight, removed first


def run_batch(
    client: Client,
    flights: list[str],
    out: str | os.PathLike,
    estimators: list[str] | None = None,
    gains: dict[str, dict[str, float]] | None = None,
    force: bool = False,
    on_result: Callable[[FlightResult], None] | None = None,
) -> BatchOutcome:
    """One task per flight not yet in the dataset at `out` (every flight with `force`), once the
    temporary files and folders a killed run left there are removed (dataset.remove_leftovers)."""
    root = Path(out).resolve()
    root.mkdir(parents=True, exist_ok=True)
    removed = dataset.remove_leftovers(root)
    done = set() if force else dataset.done_flights(root)
    todo = [f for f in flights if dataset.flight_id(f) not in done]
    skipped = [f for f in flights if dataset.flight_id(f) in done]
    futures = [
        client.submit(
            process_flight,
            str(Path(f).resolve()),
            str(root),
            estimators,
            gains,
            key=f"flight-{k}-{layout.utf8_text(f)}",
            pure=False,
        )
        for k, f in enumerate(todo)
    ]
    results = []
    result: FlightResult
    for result in completed(futures):  # a lost scheduler: ClusterLost; the flights written stay
        results.append(result)
        if on_result is not None:
            on_result(result)
    return BatchOutcome(sorted(results, key=lambda r: r.path), skipped, removed)
