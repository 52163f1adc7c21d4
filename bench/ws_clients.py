"""WebSocket viewers for the dashboard benchmarks, run as a separate process so their CPU is not
the server's: `python -m bench.ws_clients URL N SECONDS [--until-from-stdin]`
(with the flag, each client stops earlier, once it holds an onboard sample at or past the vehicle
time the caller writes on stdin). Each client reads /ws/live as fast as
it can; at the end one JSON line is printed: per client, the (vehicle time, host monotonic
receive time, the frame's server_time: when the server flushed it) of every onboard sample.
time.monotonic is the system-wide CLOCK_MONOTONIC, so the receive times compare with the
server's Message.host_time."""

from __future__ import annotations

import asyncio
import json
import sys
import time

import websockets

from gcs.server import wire


async def client(url: str, seconds: float, until: list[float]) -> list[tuple[float, float, float]]:
    """Read for `seconds`, or until holding an onboard sample at or past `until[0]` once the
    caller has set it."""
    got: list[tuple[float, float, float]] = []
    async with websockets.connect(url, max_size=None) as ws:
        end = time.monotonic() + seconds
        while time.monotonic() < end and not (until and got and got[-1][0] >= until[0]):
            try:
                message = await asyncio.wait_for(ws.recv(), 0.5)
            except TimeoutError:
                continue
            now = time.monotonic()
            if isinstance(message, str):
                continue  # hello, this client's counters
            for frame in wire.decode(message):
                if isinstance(frame, wire.PointsFrame) and "onboard" in frame.points:
                    got += [(t, now, frame.server_time) for t in frame.points["onboard"][0]]
    return got


async def main(url: str, n: int, seconds: float, until_from_stdin: bool = False) -> None:
    until: list[float] = []
    if until_from_stdin:  # the caller says when to stop: a vehicle time on one stdin line

        def read_until() -> None:
            line = sys.stdin.readline()
            until.append(float(line) if line.strip() else -float("inf"))

        asyncio.get_running_loop().run_in_executor(None, read_until)
    results = await asyncio.gather(*(client(url, seconds, until) for _ in range(n)))
    print(json.dumps(results), flush=True)


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), "--until-from-stdin" in sys.argv[4:]))
