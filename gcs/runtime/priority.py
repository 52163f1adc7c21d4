"""The live process's CPU priority: raised when the system allows it, never required.

On a machine with few cores, another program that keeps a core busy at the same priority takes
an equal share of the CPU, and the station's event loop waits in the run queue behind it: on 2
cores with such a hog, the dashboard's WebSocket p99 went from ~16 ms to 33 ms and beyond
(docs/benchmarks.md). A lower nice value puts the station ahead of ordinary programs without
realtime scheduling, whose runaway loop could freeze a machine. An ordinary user may lower it only
as far as RLIMIT_NICE allows (`nice` in /etc/security/limits.conf) or with CAP_SYS_NICE (root has
it); otherwise nothing changes and the answer says so. Processes the station starts afterwards
inherit the value (the worker lowers its own from there: gcs.runtime.station.WORKER_NICE).
"""

from __future__ import annotations

import os

#: The nice value `gcs serve` asks for by default (0: leave it).
DEFAULT_NICE = -5


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
