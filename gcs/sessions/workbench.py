"""The worker process's decoded sources and estimator runs, in bounded caches.

Replay, what-if and export of the same file should decode it once: a `Workbench` keeps the last
few sources (keyed by path, mtime and size, so a changed file is decoded again) and the last
runs of one estimator over one of them. Each worker process has one (`workbench()`); the
functions below are what the Station sends to it, and return small picklable results (or the
decoded source itself, for a replay played on the live loop).
"""

from __future__ import annotations

import dataclasses
import os
from functools import cache, lru_cache

from gcs.core.estimators import whole
from gcs.sessions.export import export
from gcs.sessions.sources import ReplaySource, SourceKey, open_source, source_key
from gcs.sessions.whatif import EstimatorRun, WhatIfView, run_estimator, what_if

#: Sources kept decoded (a flight-hour at 400 Hz is about 170 MB) and estimator runs kept.
SOURCES = 2
RUNS = 16


class Workbench:
    def __init__(self, sources: int = SOURCES, runs: int = RUNS) -> None:
        self._decode = lru_cache(maxsize=sources)(self._open)
        self._runs = lru_cache(maxsize=runs)(self._run)

    def source(self, path: str | os.PathLike) -> ReplaySource:
        """The decoded source, from the cache while its file is unchanged; InputError as open_source."""
        key = source_key(path)
        if key is None:
            return open_source(path)  # raises the InputError that names the problem
        source = self._decode(key)
        return source if source.path == str(path) else dataclasses.replace(source, path=str(path))

    def run(self, source: ReplaySource, name: str, pinned: dict[str, float]) -> EstimatorRun:
        if source.key is None:
            return run_estimator(source, name, pinned)
        return self._runs(source.key, name, tuple(sorted(pinned.items())))

    def cache_info(self) -> tuple[int, int]:
        """(sources, runs) held now."""
        return self._decode.cache_info().currsize, self._runs.cache_info().currsize

    @staticmethod
    def _open(key: SourceKey) -> ReplaySource:
        return open_source(key[0])

    def _run(self, key: SourceKey, name: str, pinned: tuple[tuple[str, float], ...]) -> EstimatorRun:
        return run_estimator(self._decode(key), name, dict(pinned))


@cache
def workbench() -> Workbench:
    """This process's workbench."""
    return Workbench()


def warm_up() -> None:
    """This module's imports and the whole-run kernels: sent once at server start, so the first
    replay or what-if does not wait for the worker process to spawn, import gcs and compile."""
    workbench()
    whole.warm()


def load_source(path: str | os.PathLike) -> ReplaySource:
    return workbench().source(path)


def what_if_view(path: str | os.PathLike, estimator: str, gains: dict[str, float]) -> WhatIfView:
    """`what_if(...).view()` over the source at path."""
    bench = workbench()
    return what_if(bench.source(path), estimator, gains, bench.run).view()


def export_file(path: str | os.PathLike, fmt: str, out: str | os.PathLike) -> int:
    """Export `path` to `out` in `fmt` (gcs.sessions.export), decoding through the workbench;
    returns what export.UNITS[fmt] counts."""
    return export(path, fmt, out, workbench().source)
