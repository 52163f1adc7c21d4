"""Per-link counters and measured rates (per message type and bytes), as a field engineer
reads them: what arrives, how fast, and what was lost or damaged on the way."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

from gcs.mavlink.framing import FramingCounters
from gcs.runtime.snapshots import LinkCounters


@dataclass
class LinkStats:
    counts: dict[str, int] = field(default_factory=dict)  # packets received per message type
    #: sysid → its packets per message type, from its first packet on: a vehicle's own figures on a
    #: link it shares (gcs.runtime.vehicle_link), its packets before its first heartbeat included
    by_system: dict[int, dict[str, int]] = field(default_factory=dict)
    nonfinite: dict[str, int] = field(default_factory=dict)  # packets refused for a non-finite value, per type
    kernel_drops: int = 0  # datagrams the kernel dropped before we read them (SO_RXQ_OVFL), this link
    bytes_in: int = 0
    bytes_out: int = 0
    packets_out: int = 0
    framing: FramingCounters = field(default_factory=FramingCounters)
    window: float = 5.0  # s over which rates are measured
    _history: deque = field(default_factory=deque, repr=False)

    def follow(self, counts: dict[str, int], now: float) -> None:
        """Count from `counts` (kept up to date elsewhere: a vehicle's system's on a shared link)
        from `now` (host monotonic s): the rates start again from the totals now, their history
        being of other counts, so the next `sample` gives them (not the one after)."""
        if counts is not self.counts:
            self.counts = counts
            self._history.clear()
            self.sample(now)

    def sample(self, now: float) -> None:
        """Remember the totals at `now` (host monotonic s); call about once a second."""
        self._history.append((now, self.bytes_in, dict(self.counts)))
        while len(self._history) > 2 and now - self._history[1][0] >= self.window:
            self._history.popleft()

    def _span(self):
        if len(self._history) < 2:
            return None
        (t0, b0, c0), (t1, b1, c1) = self._history[0], self._history[-1]
        return (t1 - t0, b1 - b0, c0, c1) if t1 > t0 else None

    def rates(self) -> dict[str, float]:
        """Packets/s per message type over the last `window` seconds."""
        span = self._span()
        if span is None:
            return {}
        dt, _, c0, c1 = span
        return {k: (v - c0.get(k, 0)) / dt for k, v in sorted(c1.items())}

    def bytes_per_second(self) -> float:
        span = self._span()
        return span[1] / span[0] if span else 0.0

    def packets_lost(self) -> int:
        return sum(self.framing.lost.values())

    def loss_fraction(self) -> float:
        lost = self.packets_lost()
        total = self.framing.packets + lost
        return lost / total if total else 0.0

    def snapshot(self) -> LinkCounters:
        f = self.framing
        return LinkCounters(
            packets=f.packets,
            bytes_in=self.bytes_in,
            bytes_out=self.bytes_out,
            packets_out=self.packets_out,
            bytes_per_s=round(self.bytes_per_second(), 1),
            rates_hz={k: round(v, 2) for k, v in self.rates().items()},
            counts=dict(sorted(self.counts.items())),
            crc_errors=f.crc_errors,
            malformed=f.malformed,
            bytes_skipped=f.bytes_skipped,
            unknown_messages=f.unknown,
            packets_lost=self.packets_lost(),
            loss_fraction=round(self.loss_fraction(), 5),
            lost_by_source={f"{s}/{c}": n for (s, c), n in sorted(f.lost.items())},
            mavlink1_packets=f.mavlink1,
            mavlink2_packets=f.mavlink2,
            nonfinite_rejected=dict(sorted(self.nonfinite.items())),
            kernel_drops=self.kernel_drops,
        )
