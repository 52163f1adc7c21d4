"""Where the tasks run: a Dask `LocalCluster` on this machine by default, or any running
scheduler by address (`tcp://host:8786`) for a real cluster.

The local cluster uses processes (the estimators are pure Python: threads would share one GIL),
one thread each, a few workers; its HTTP server (and dashboard, with bokeh installed) is on a free
port, printed when asked for. Dask's own
text progress bar is shown when stderr is a terminal, and nothing in CI logs or pipes.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
from collections.abc import Iterator, Sequence

from distributed import Client, Future, LocalCluster, as_completed
from distributed.diagnostics.progressbar import TextProgressBar

#: Local workers by default: the machine's cores, at most 4 (a laptop stays usable).
DEFAULT_WORKERS = max(1, min(4, os.cpu_count() or 1))


@contextlib.contextmanager
def connect(scheduler: str | None = None, workers: int | None = None, dashboard: bool = False) -> Iterator[Client]:
    """A client of the scheduler at `scheduler`, or of a LocalCluster of `workers` processes."""
    if scheduler:
        with Client(scheduler, timeout="30s") as client:
            yield client
        return
    with (
        LocalCluster(
            n_workers=workers or DEFAULT_WORKERS,
            threads_per_worker=1,
            processes=True,
            dashboard_address=":0",  # the scheduler's HTTP server: a free port, never a clash on 8787
            silence_logs=logging.ERROR,  # not the nanny's "still alive after 4 s, killing" at close
        ) as cluster,
        Client(cluster) as client,
    ):
        if dashboard:
            print(f"dask dashboard: {client.dashboard_link}", file=sys.stderr)
        yield client


def completed(futures: Sequence[Future]) -> Iterator[Future]:
    """The futures as they finish, with Dask's progress bar on a terminal."""
    if futures and sys.stderr.isatty():
        TextProgressBar(list(futures), interval="0.5s", start=True)
    yield from as_completed(futures)
