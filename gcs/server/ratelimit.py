"""Per-client limits on the endpoints that cost seconds of worker time or radio time: what-if,
export, loading a replay, a parameter download. A token bucket per client address and endpoint:
`burst` requests at once, then `per_minute`. A script stuck in a loop, or a page hammering an
export link, gets 429 with Retry-After (and an entry in the audit log) instead of queueing minutes
of work ahead of the operator's own requests."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

from fastapi import HTTPException, Request, status

from gcs.server.deps import get_client

#: Buckets kept per limit before the idlest are forgotten (a flood of spoofed addresses must not
#: grow memory without bound).
MAX_CLIENTS = 1024


@dataclass
class RateLimit:
    name: str
    per_minute: float
    burst: int
    _buckets: dict[str, tuple[float, float]] = field(default_factory=dict)  # client -> (tokens, updated)

    def take(self, client: str, now: float) -> float:
        """Spend one request of `client`: 0 when allowed, else the seconds until it would be."""
        tokens, updated = self._buckets.pop(client, (float(self.burst), now))
        tokens = min(float(self.burst), tokens + (now - updated) * self.per_minute / 60.0)
        wait = 0.0 if tokens >= 1.0 else (1.0 - tokens) * 60.0 / self.per_minute
        self._buckets[client] = (tokens - 1.0 if wait == 0.0 else tokens, now)  # newest last
        while len(self._buckets) > MAX_CLIENTS:
            del self._buckets[next(iter(self._buckets))]
        return wait


def default_limits() -> dict[str, RateLimit]:
    """The limits of one app, by endpoint (fresh buckets per app)."""
    return {
        limit.name: limit
        for limit in (
            RateLimit("whatif", per_minute=10, burst=4),
            RateLimit("export", per_minute=30, burst=8),
            RateLimit("replay", per_minute=20, burst=6),
            RateLimit("params download", per_minute=6, burst=3),
            RateLimit("onboard log download", per_minute=6, burst=3),
        )
    }


def rate_limited(name: str):
    """A dependency that refuses a client over the `name` limit with 429."""

    async def check(request: Request) -> None:
        limit: RateLimit = request.app.state.rate_limits[name]
        wait = limit.take(request.client.host if request.client else "?", time.monotonic())
        if wait > 0:
            request.app.state.station.events.record(
                "refused", await get_client(request), reason="rate", path=request.url.path
            )
            raise HTTPException(
                status.HTTP_429_TOO_MANY_REQUESTS,
                detail=f"too many {name} requests from this client: at most {limit.per_minute:g} a minute "
                f"({limit.burst} at once); try again in {math.ceil(wait)} s",
                headers={"Retry-After": str(math.ceil(wait))},
            )

    return check
