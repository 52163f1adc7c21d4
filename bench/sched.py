"""A thread's CPU time and run-queue wait from Linux's /proc/PID/task/TID/schedstat: how long it
ran, and how long it was runnable but waiting for a core. The wait is the scheduler's share of a
latency: a thread that waited 30 ms for a core answered 30 ms late whatever its code does."""

from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True, slots=True)
class Sched:
    cpu_s: float
    run_delay_s: float
    slices: int

    def __sub__(self, earlier: Sched) -> Sched:
        return Sched(self.cpu_s - earlier.cpu_s, self.run_delay_s - earlier.run_delay_s, self.slices - earlier.slices)


def thread_sched(pid: int | str = "self", tid: int | None = None) -> Sched:
    """One thread's figures (default: the calling thread; a process's main thread has tid = pid).
    Zeros when the thread is gone."""
    tid = tid if tid is not None else (threading.get_native_id() if pid == "self" else int(pid))
    try:
        on_cpu, waited, slices = Path(f"/proc/{pid}/task/{tid}/schedstat").read_text().split()
    except (OSError, ValueError):
        return Sched(0.0, 0.0, 0)
    return Sched(int(on_cpu) * 1e-9, int(waited) * 1e-9, int(slices))


def process_sched(pid: int) -> Sched:
    """The sum over a process's threads now alive."""
    total = Sched(0.0, 0.0, 0)
    for task in Path(f"/proc/{pid}/task").glob("*"):
        s = thread_sched(pid, int(task.name))
        total = Sched(total.cpu_s + s.cpu_s, total.run_delay_s + s.run_delay_s, total.slices + s.slices)
    return total
