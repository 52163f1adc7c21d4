"""Where `gcs serve`'s event loop stalls: every callback longer than SLOW_MS, what it was doing,
and how late the loop answers, under the PX4-like stream with pages open.

    python -m bench.loop_stalls [--seconds 20] [--rate 1000] [--pages 5] [--ws 20] [--hog]

The server is `gcs serve` (3 estimators, recording, the 3-D view) in its own process with a
probe installed before it starts (`python -m bench.loop_stalls --child -- SERVE ARGS`):
- every event-loop callback (asyncio `Handle._run`: task steps, timers, I/O callbacks) is timed,
  wall and the loop thread's CPU; one above SLOW_MS is kept;
- a sampler thread looks at the loop thread's stack every SAMPLE_MS while a callback has run for
  more than SAMPLE_MS, so a slow callback comes with where its time went (the innermost frames
  in gcs, else the innermost frames);
- garbage-collector passes are timed (`gc.callbacks`);
- the same thread asks the loop to run a no-op every PROBE_MS (`call_soon_threadsafe`) and
  records how late it ran: the delay any callback sees, whatever caused it.
A callback whose wall time is far above its CPU time was not running: the process was waiting
for a core (the machine's load), or for the GIL (another thread of the process).
The senders are bench.serve_cpu's (stream, pollers) and bench.ws_clients, each its own process.
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import gc
import json
import os
import resource
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from bench.serve_cpu import pollers, run_sender, wait_until_serving
from gcs.commands.cli import main as gcs_main
from gcs.runtime import event_loop
from gcs.transport.address import free_port

SLOW_MS = 5.0
SAMPLE_MS = 1.0
PROBE_MS = 2.0
STACK_DEPTH = 4


class Probe:
    """Installed in the server process before its loop starts."""

    def __init__(self) -> None:
        self.slow: list[dict[str, Any]] = []
        self.gc_pauses: list[tuple[int, float]] = []
        self.lags: list[float] = []
        self.callbacks = 0
        self.loop: asyncio.AbstractEventLoop | None = None
        self.loop_thread = 0
        self._running: tuple[float, object] | None = None
        self._samples: collections.Counter[str] = collections.Counter()
        self._gc_start = self._gc_cpu = 0.0
        self._threads_at_reset: dict[str, float] = {}
        self._threads_while_serving: dict[str, float] = {}
        self.heap: dict[str, Any] = {}
        self._modules_at_reset: set[str] = set()
        self._stop = threading.Event()

    def install(self) -> None:
        self._original = original = asyncio.events.Handle._run
        probe = self

        def timed_run(handle: asyncio.events.Handle) -> None:
            if probe.loop is None:
                probe.loop, probe.loop_thread = handle._loop, threading.get_ident()  # type: ignore[attr-defined]
                threading.Thread(target=probe._watch, daemon=True, name="loop-probe").start()
            wall, cpu = time.perf_counter(), time.thread_time()
            usage = resource.getrusage(resource.RUSAGE_THREAD)
            probe._running = (wall, handle)
            try:
                original(handle)
            finally:
                probe._running = None
                probe.callbacks += 1
                ms = 1000 * (time.perf_counter() - wall)
                if ms > SLOW_MS:
                    after = resource.getrusage(resource.RUSAGE_THREAD)
                    probe.slow.append(
                        {
                            "ms": round(ms, 2),
                            "cpu_ms": round(1000 * (time.thread_time() - cpu), 2),
                            # preempted by the OS (a core's queue) / waited itself (the GIL, a lock)
                            "preempted": after.ru_nivcsw - usage.ru_nivcsw,
                            "waited": after.ru_nvcsw - usage.ru_nvcsw,
                            "callback": _describe(handle),
                            "where": dict(probe._samples.most_common(3)),
                        }
                    )
                probe._samples.clear()

        asyncio.events.Handle._run = timed_run  # type: ignore[method-assign]
        gc.callbacks.append(self._on_gc)

    def uninstall(self) -> None:
        asyncio.events.Handle._run = self._original  # type: ignore[method-assign]
        gc.callbacks.remove(self._on_gc)
        self._stop.set()

    def _on_gc(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self._gc_start, self._gc_cpu = time.perf_counter(), time.thread_time()
        elif threading.get_ident() == self.loop_thread:
            ms = 1000 * (time.perf_counter() - self._gc_start)
            self.gc_pauses.append((info["generation"], ms, 1000 * (time.thread_time() - self._gc_cpu)))

    def look_at_heap(self, *_: object) -> None:
        """What a full collection walks while serving (SIGUSR2, before the stop releases the frozen)."""
        self._threads_while_serving = _thread_cpu()  # the recording's writer is gone after the stop
        walked = gc.get_objects()
        self.heap = {
            "frozen": gc.get_freeze_count(),
            "walked_by_a_full_pass": len(walked),
            "by_type": dict(collections.Counter(_type_name(o) for o in walked).most_common(10)),
            "modules_imported_since_the_clients_connected": sorted(
                {name.split(".")[0] for name in set(sys.modules) - self._modules_at_reset}
            ),
        }

    def reset(self, *_: object) -> None:
        """Start counting now (SIGUSR1: the clients are connected; start-up is not measured)."""
        self.slow.clear()
        self.gc_pauses.clear()
        self.lags.clear()
        self.callbacks = 0
        self._threads_at_reset = _thread_cpu()
        self._modules_at_reset = set(sys.modules)

    def _watch(self) -> None:
        next_probe = time.perf_counter()
        while not self._stop.wait(SAMPLE_MS / 1000):
            now = time.perf_counter()
            running = self._running
            if running is not None and now - running[0] > SAMPLE_MS / 1000:
                frame = sys._current_frames().get(self.loop_thread)
                if frame is not None:
                    self._samples[_stack(frame)] += 1
            if now >= next_probe and self.loop is not None and not self.loop.is_closed():
                next_probe = now + PROBE_MS / 1000
                try:
                    self.loop.call_soon_threadsafe(self._answered, now)
                except RuntimeError:
                    return  # the loop closed

    def _answered(self, asked: float) -> None:
        self.lags.append(1000 * (time.perf_counter() - asked))

    def report(self) -> dict[str, Any]:
        self._stop.set()
        lags = sorted(self.lags) or [0.0]
        groups: dict[str, dict[str, Any]] = {}
        for s in self.slow:
            where = next(iter(s["where"]), "")
            key = f"{s['callback']} @ {where}"
            g = groups.setdefault(key, {"n": 0, "total_ms": 0.0, "max_ms": 0.0, "cpu_ms": 0.0})
            g["n"] += 1
            g["total_ms"] = round(g["total_ms"] + s["ms"], 1)
            g["cpu_ms"] = round(g["cpu_ms"] + s["cpu_ms"], 1)
            g["max_ms"] = max(g["max_ms"], s["ms"])
        gcs = [ms for _, ms, _ in self.gc_pauses]
        threads = self._threads_while_serving or _thread_cpu()
        return {
            "callbacks": self.callbacks,
            "slow": len(self.slow),
            "slow_groups": dict(sorted(groups.items(), key=lambda kv: -kv[1]["total_ms"])),
            "slowest": sorted(self.slow, key=lambda s: -s["ms"])[:15],
            "gc": {
                "passes": len(gcs),
                "by_generation": dict(collections.Counter(g for g, _, _ in self.gc_pauses)),
                "max_ms": round(max(gcs, default=0.0), 2),
                "over_slow": sum(ms > SLOW_MS for ms in gcs),
                "gen2_ms_cpu_ms": [(round(ms, 1), round(cpu, 1)) for g, ms, cpu in self.gc_pauses if g == 2][:20],
            },
            "heap_while_serving": self.heap,
            "thread_cpu_s": {
                name: round(cpu - self._threads_at_reset.get(name, 0.0), 2)
                for name, cpu in sorted(threads.items(), key=lambda kv: -kv[1])
            },
            "lag_ms": {
                "n": len(self.lags),
                "p50": round(lags[len(lags) // 2], 2),
                "p99": round(lags[int(0.99 * (len(lags) - 1))], 2),
                "max": round(lags[-1], 2),
                "over_slow": sum(x > SLOW_MS for x in lags),
            },
        }


def _thread_cpu() -> dict[str, float]:
    """CPU seconds of each thread of this process (Linux /proc), by name and id."""
    out = {}
    names = {t.native_id: t.name for t in threading.enumerate()}
    tick = os.sysconf("SC_CLK_TCK")
    for task in Path("/proc/self/task").iterdir():
        try:
            stat = (task / "stat").read_text()
        except OSError:
            continue
        name = names.get(int(task.name)) or stat[stat.index("(") + 1 : stat.rindex(")")]
        fields = stat[stat.rindex(")") + 2 :].split()
        out[f"{name} {task.name}"] = (int(fields[11]) + int(fields[12])) / tick
    return out


def _type_name(o: object) -> str:
    module = getattr(type(o), "__module__", None)
    return f"{module if isinstance(module, str) else '?'}.{type(o).__qualname__}"


def _describe(handle: object) -> str:
    callback = getattr(handle, "_callback", None)
    owner = getattr(callback, "__self__", None)
    if isinstance(owner, asyncio.Task):  # a task step: name the coroutine
        return f"task {owner.get_coro().__qualname__}"  # type: ignore[union-attr]
    name = getattr(callback, "__qualname__", None) or type(callback).__name__
    return str(name)


def _stack(frame: Any) -> str:
    """The innermost STACK_DEPTH frames, the first of them in gcs when there is one."""
    frames = []
    while frame is not None:
        frames.append(frame)
        frame = frame.f_back
    ours = [i for i, f in enumerate(frames) if "/gcs/" in f.f_code.co_filename]
    start = ours[0] if ours else 0
    shown = frames[start : start + STACK_DEPTH]
    return " < ".join(f"{Path(f.f_code.co_filename).name}:{f.f_lineno} {f.f_code.co_name}" for f in shown)


def child(report_path: str, serve_args: list[str]) -> None:
    """The server process: the probe, then `gcs serve` until SIGINT; the report on the way out."""
    probe = Probe()
    probe.install()
    # the probe times asyncio's Handle._run: uvloop's callbacks are not Python Handles, so the
    # server runs here on asyncio's own loop (the loop-answer probe would work on either)
    event_loop.loop_factory = lambda: None  # type: ignore[assignment]
    signal.signal(signal.SIGUSR1, probe.reset)
    signal.signal(signal.SIGUSR2, probe.look_at_heap)
    try:
        gcs_main(["serve", *serve_args])
    except KeyboardInterrupt:
        pass
    finally:
        Path(report_path).write_text(json.dumps(probe.report()))


def run(seconds: float, rate: int, pages: int, ws: int, hog: bool) -> dict[str, Any]:
    port, http = free_port(), free_port()
    with tempfile.TemporaryDirectory() as tmp:
        report = os.path.join(tmp, "report.json")
        serve = ["--connect", f"udpin:127.0.0.1:{port}", "--port", str(http), "--record-dir", tmp, "--token", "bench"]
        server = subprocess.Popen(
            [sys.executable, "-m", "bench.loop_stalls", "--child", report, "--", *serve],
            stdout=subprocess.DEVNULL,
        )
        base = f"http://127.0.0.1:{http}"
        wait_until_serving(base)
        helpers = [run_sender(port, rate, seconds + 4)]
        time.sleep(2.0)  # the estimators' kernels load; streams start
        spinner = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if hog else None
        helpers.append(pollers(base, seconds, pages))
        helpers.append(
            subprocess.Popen(
                [sys.executable, "-m", "bench.ws_clients", f"ws://127.0.0.1:{http}/ws/live", str(ws), str(seconds)],
                stdout=subprocess.DEVNULL,
            )
        )
        time.sleep(2.0)  # clients connect
        server.send_signal(signal.SIGUSR1)
        for h in helpers:
            h.wait(seconds + 60)
        if spinner is not None:
            spinner.kill()
            spinner.wait()
        server.send_signal(signal.SIGUSR2)
        time.sleep(1.0)
        server.send_signal(signal.SIGINT)
        server.wait(60)
        result: dict[str, Any] = json.loads(Path(report).read_text())
    result["load_avg_1m"] = round(os.getloadavg()[0], 2)
    return result


def main() -> list[dict[str, Any]]:
    r = run(20.0, 1000, 5, 20, False)
    return [
        {
            "benchmark": "gcs serve event loop: callbacks > 5 ms, loop answer delay (1000 msg/s, 5 pages, 20 WS)",
            "slow_callbacks": r["slow"],
            "callbacks": r["callbacks"],
            "lag_p99_ms": r["lag_ms"]["p99"],
            "lag_max_ms": r["lag_ms"]["max"],
            "gc_max_ms": r["gc"]["max_ms"],
            "load_avg_1m": r["load_avg_1m"],
        }
    ]


if __name__ == "__main__":
    if "--child" in sys.argv:
        i = sys.argv.index("--child")
        child(sys.argv[i + 1], sys.argv[sys.argv.index("--") + 1 :])
    else:
        parser = argparse.ArgumentParser(description=__doc__)
        parser.add_argument("--seconds", type=float, default=20.0)
        parser.add_argument("--rate", type=int, default=1000)
        parser.add_argument("--pages", type=int, default=5)
        parser.add_argument("--ws", type=int, default=20)
        parser.add_argument("--hog", action="store_true")
        a = parser.parse_args()
        print(json.dumps(run(a.seconds, a.rate, a.pages, a.ws, a.hog), indent=1))
