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
from concurrent.futures import CancelledError
from typing import Any

from distributed import Client, Future, LocalCluster, as_completed
from distributed.diagnostics.progressbar import TextProgressBar

#: Local workers by default: the machine's cores, at most 4 (a laptop stays usable).
DEFAULT_WORKERS = max(1, min(4, os.cpu_count() or 1))


@contextlib.contextmanager
def connect(scheduler: str | None = None, workers: int | None = None, dashboard: bool = False) -> Iterator[Client]:
    """A client of the scheduler at `scheduler`, or of a LocalCluster of `workers` processes."""
    if scheduler:
        with _client_logs_quiet(), Client(scheduler, timeout="30s") as client:
            yield client
        return
    with (
        LocalCluster(
            n_workers=workers or DEFAULT_WORKERS,
            threads_per_worker=1,
            processes=True,
            dashboard_address=":0",  # the scheduler's HTTP server: a free port, never a clash on 8787
            # not the nanny's "still alive after 4 s, killing" at close, nor a worker's "Compute
            # Failed" with the task's traceback: the command says a task's error in one line
            silence_logs=logging.CRITICAL,
        ) as cluster,
        Client(cluster) as client,
    ):
        if dashboard:
            print(f"dask dashboard: {client.dashboard_link}", file=sys.stderr)
        yield client


@contextlib.contextmanager
def _client_logs_quiet() -> Iterator[None]:
    """Dask's client logs nothing of its own meanwhile: a lost scheduler reaches the command as
    ClusterLost, said in one line, where the client also logged the traceback of its reconnection
    being cancelled at close."""
    logger = logging.getLogger("distributed.client")
    level = logger.level
    logger.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        logger.setLevel(level)


class ClusterLost(OSError):
    """The scheduler went away (or cancelled the run's tasks) before every task finished: an OSError,
    so a command says it in one line as it says a scheduler it cannot reach, not with Dask's
    traceback. What finished before is kept (each task writes its own output)."""


def completed(futures: Sequence[Future]) -> Iterator[Any]:
    """The futures' results as they finish (each future released: nothing stays on the cluster),
    with Dask's progress bar on a terminal; ClusterLost when the scheduler is lost on the way. A
    task that raised (its output's disk full: a flight's own errors are its failure row) raises
    its own error here, which was taken for a lost scheduler when it was an OSError."""
    if futures and sys.stderr.isatty():
        TextProgressBar(list(futures), interval="0.5s", start=True)
    done, failed = 0, None
    try:
        for future in as_completed(futures):
            if future.status == "error":
                failed = future
                break
            result = future.result()
            future.release()
            done += 1
            yield result
    except (CancelledError, OSError) as exc:  # FutureCancelledError, CommClosedError
        reason = getattr(exc, "reason", None) or str(exc) or type(exc).__name__  # "scheduler-connection-lost"
        raise ClusterLost(f"lost the Dask scheduler after {done} of {len(futures)} tasks ({reason})") from None
    if failed is not None:
        raise failed.exception()
