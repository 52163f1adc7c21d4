"""The live process's CPU priority: raised on request when the system allows it, never required.

On a machine with few cores, another program that keeps a core busy at the same priority takes
an equal share of the CPU, and the station's event loop waits in the run queue behind it. A lower
nice value (`gcs serve --nice -5`) puts the station ahead of ordinary programs without realtime
scheduling, whose runaway loop could freeze a machine. It is not the default: measured with the
pages on the same machine (bench.ws_latency), the station at nice -5 made the pages' own process
wait more and the WebSocket p99 worse (87-99 ms against 19-25 ms at nice 0, docs/benchmarks.md);
it is for a station whose viewers are elsewhere. An ordinary user may lower it only as far as
RLIMIT_NICE allows (`nice` in /etc/security/limits.conf) or with CAP_SYS_NICE (root has it);
otherwise nothing changes and the answer says so. Processes the station starts afterwards inherit
the value (the worker lowers its own from there: gcs.runtime.station.WORKER_NICE).
"""

from __future__ import annotations

import os

#: The nice value bench.ws_latency measures a raised station at (`gcs serve --nice`).
RAISED_NICE = -5


def raise_priority(nice: int) -> str:
    """Set this process's nice value to `nice` if that raises it and is permitted; one line
    saying what the process now runs at and why."""
    current = os.getpriority(os.PRIO_PROCESS, 0)
    if nice >= current:
        return f"priority: nice {current} (left as it was)"
    try:
        os.setpriority(os.PRIO_PROCESS, 0, nice)
    except PermissionError:
        return (
            f"priority: nice {current} (nice {nice} not permitted: needs CAP_SYS_NICE or a RLIMIT_NICE "
            f"of {20 - nice}, e.g. '<user> - nice {nice}' in /etc/security/limits.conf)"
        )
    return f"priority: nice {os.getpriority(os.PRIO_PROCESS, 0)} (raised from {current})"
