"""3-D view clients for the dashboard benchmarks: what each real page's viser iframe asks of the
server. Run as a separate process so their CPU is not the server's:
`python -m bench.viser_clients URL N SECONDS` (URL: ws://host:viser_port).

Each client speaks viser's own WebSocket protocol as the page's iframe does: it announces its
camera (viser counts a client as connected from then on, and the station then draws the pose view
for it, gcs.server.pose_refresh) and reads every message the server sends, without decoding
them (the browser's work, not the server's). At the end one JSON line is printed: per client, the
messages and bytes received.
"""

from __future__ import annotations

import asyncio
import json
import sys
import time

import msgspec
import viser
import websockets
from viser import _messages as viser_messages


def camera_message() -> bytes:
    """The camera a page's 3-D view announces when it opens (the view's default pose)."""
    camera = viser_messages.ViewerCameraMessage(
        wxyz=(1.0, 0.0, 0.0, 0.0),
        position=(-2.2, -2.2, 1.4),
        fov=1.0,
        near=0.01,
        far=100.0,
        image_height=480,
        image_width=640,
        look_at=(0.0, 0.0, 0.0),
        up_direction=(0.0, 0.0, 1.0),
    )
    return msgspec.msgpack.encode(camera.as_serializable_dict())


async def client(url: str, seconds: float) -> tuple[int, int]:
    """Watch for `seconds`: (messages, bytes) received."""
    messages = size = 0
    async with websockets.connect(url, subprotocols=[f"viser-v{viser.__version__}"], max_size=None) as ws:
        await ws.send(camera_message())
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            try:
                frame = await asyncio.wait_for(ws.recv(), left)
            except TimeoutError:
                break
            messages += 1
            size += len(frame)
    return messages, size


async def main(url: str, n: int, seconds: float) -> None:
    results = await asyncio.gather(*(client(url, seconds) for _ in range(n)))
    print(json.dumps(results), flush=True)


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], int(sys.argv[2]), float(sys.argv[3])))
