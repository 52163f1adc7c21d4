"""Live data for the page: WS /ws/live pushes every attitude sample of every source as it
arrives (frames of ≤ 10 ms, see gcs.server.live), and GET /api/history fills a new page's window
from the live store at once (every sample, or min/max per plot column with `columns`, with each
estimator's error against onboard and truth), and a reconnecting page's gap (`since`).

Messages on /ws/live:
* binary: one message per client per send, every frame queued for it since the last one
  (`gcs.server.wire`: points as float arrays per source, vehicle seconds and degrees; a gain
  change as a JSON frame `{"type":"gain",...}`, the event log record, in order with the points;
  likewise a reset to a preset and a vehicle parameter's new value, `{"type":"param value",...}`);
* text, JSON: `{"type":"hello","client":ID,"history_s":S}` once, and
  `{"type":"client",...}`, this client's counters (sent, dropped), about once a second.
"""

from __future__ import annotations

import asyncio

from fastapi import APIRouter, Query, WebSocket, WebSocketDisconnect
from fastapi.responses import Response

from gcs.core import strict_json
from gcs.server.client_feed import ClientFeed
from gcs.server.deps import HubDep, StationDep
from gcs.server.models import History
from gcs.server.ws_direct import direct_write

router = APIRouter(tags=["live"])

#: Seconds between a client's own counter messages.
CLIENT_STATS_PERIOD = 1.0


@router.get("/api/history", response_model=History)
async def get_history(
    hub: HubDep,
    station: StationDep,
    seconds: float = Query(60.0, gt=0, le=3600, description="vehicle seconds back from the newest sample"),
    since: float | None = Query(
        None, allow_inf_nan=False, description="instead: every sample after this vehicle time (a page catching up)"
    ),
    columns: int | None = Query(
        None, ge=10, le=20_000, description="plot columns: above two samples per column, min/max per column"
    ),
) -> Response:
    # Encoded here, not validated by pydantic: a 10-minute window is a million numbers.
    h = hub.history(seconds, since=since, columns=columns, estimators=tuple(station.estimator_names()))
    body = strict_json.dumps(
        {"seconds": h.seconds, "resolution_s": h.resolution_s, "points": h.points, "errors": h.errors},
        separators=(",", ":"),
    )
    return Response(body, media_type="application/json")


@router.websocket("/ws/live")
async def live(ws: WebSocket, hub: HubDep) -> None:
    await ws.accept()
    feed = hub.connect(f"{ws.client.host}:{ws.client.port}" if ws.client else "?")
    stats: asyncio.Task[None] | None = None
    try:
        await ws.send_text(strict_json.dumps({"type": "hello", "client": feed.id, "history_s": hub.seconds}))
        # the hub writes the frames from here on (gcs.server.client_feed.ClientFeed), straight to the
        # socket where the server offers it (gcs.server.ws_direct)
        feed.attach(ws.send_bytes, direct_write(ws.scope))
        stats = asyncio.create_task(send_stats(ws, feed))
        # The page sends nothing we need; reading notices the disconnect. Whatever a client sends
        # (text or binary) is read and ignored, never an error.
        while (await ws.receive())["type"] != "websocket.disconnect":
            pass
    except WebSocketDisconnect:
        pass
    finally:
        hub.disconnect(feed)
        if stats is not None:
            stats.cancel()
            await asyncio.gather(stats, return_exceptions=True)


async def send_stats(ws: WebSocket, feed: ClientFeed) -> None:
    """This client's counters, about once a second."""
    while True:
        await asyncio.sleep(CLIENT_STATS_PERIOD)
        await ws.send_text(strict_json.dumps({"type": "client", **feed.snapshot().as_dict()}))
