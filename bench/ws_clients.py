"""WebSocket viewers for the dashboard benchmarks, run as a separate process so their CPU is not
the server's: `python -m bench.ws_clients URL N SECONDS`. Each client reads /ws/live as fast as
it can; at the end one JSON line is printed: per client, the (vehicle time, host monotonic
receive time) of every onboard sample. time.monotonic is the system-wide CLOCK_MONOTONIC, so
the receive times compare with the server's Message.host_time."""

from __future__ import annotations

import asyncio
import json
import sys
import time

import websockets


async def client(url: str, seconds: float) -> list[tuple[float, float]]:
    got = []
    async with websockets.connect(url, max_size=None) as ws:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                text = await asyncio.wait_for(ws.recv(), 0.5)
            except TimeoutError:
                continue
            now = time.monotonic()
            msg = json.loads(text)
            for frame in msg["frames"] if msg["type"] == "batch" else [msg]:
                if frame["type"] == "points" and "onboard" in frame["points"]:
                    got += [(t, now) for t in frame["points"]["onboard"][0]]
    return got


async def main(url: str, n: int, seconds: float) -> None:
    results = await asyncio.gather(*(client(url, seconds) for _ in range(n)))
    print(json.dumps(results))


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], int(sys.argv[2]), float(sys.argv[3])))
