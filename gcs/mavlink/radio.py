"""The bandwidth budget of a telemetry radio: what a 3DR / SiK link carries, what each message
costs on the wire, and which stream rates fit (the station's gcs.runtime.radio and the
simulator's gcs.sim.radio share these figures).

A serial byte costs 10 bits (8N1), so 57600 baud carries 5760 bytes/s into the radio; SiK's air
protocol (packet headers, TDM slots, the uplink's share) leaves about SIK_EFFICIENCY of that for
the downlink (a modelled figure, typical of a 64 kbps air rate; a real link may carry less in
noise). A MAVLink 1 frame is its payload + 8 bytes, a MAVLink 2 frame its payload + 12 (an upper
bound: MAVLink 2 trims trailing zero bytes; + 13 when signed).
"""

from __future__ import annotations

from dataclasses import dataclass

from pymavlink.dialects.v10 import ardupilotmega as mavlink1_dialect

from gcs.mavlink.dialect import mavlink

SIK_EFFICIENCY = 0.8
FRAME_OVERHEAD = {1: 8, 2: 12}


def link_capacity(baud: int, efficiency: float = SIK_EFFICIENCY) -> float:
    """Bytes per second a SiK radio at `baud` carries from vehicle to ground."""
    return baud / 10.0 * efficiency


def frame_bytes(name: str, mavlink_version: int) -> int:
    """Bytes of one `name` packet on the wire (MAVLink 1 has no extension fields)."""
    if mavlink_version == 1:
        cls = getattr(mavlink1_dialect, f"MAVLink_{name.lower()}_message", None)
        if cls is not None:
            return int(cls.unpacker.size) + FRAME_OVERHEAD[1]
    cls = getattr(mavlink, f"MAVLink_{name.lower()}_message")
    return int(cls.unpacker.size) + FRAME_OVERHEAD[mavlink_version if mavlink_version in (1, 2) else 2]


@dataclass(frozen=True, slots=True)
class RatePrediction:
    """Rates (Hz) that fit `budget_bps` next to `background_bps`, and what they cost."""

    scale: float  # 1 = everything as wanted
    rates: dict[str, float]
    cost_bps: dict[str, float]  # per message at the predicted rate
    budget_bps: float
    background_bps: float

    @property
    def total_bps(self) -> float:
        return sum(self.cost_bps.values()) + self.background_bps


def rates_at_scale(
    wanted: dict[str, float], scale: float, keep_hz: float = 5.0, whole_hz: bool = False
) -> dict[str, float]:
    """The fast streams (above keep_hz) scaled, never below keep_hz; whole Hz for stream groups."""
    rates = {name: hz if hz <= keep_hz else max(keep_hz, hz * scale) for name, hz in wanted.items()}
    return {name: float(int(hz + 1e-6)) for name, hz in rates.items()} if whole_hz else rates


def stream_costs(
    rates: dict[str, float], mavlink_version: int, groups: dict[str, int] | None = None
) -> dict[str, float]:
    """Bytes/s of each stream at `rates`; with `groups` (REQUEST_DATA_STREAM), a member is sent
    at its group's rate, the highest asked of any member."""
    top: dict[int, float] = {}
    for name, hz in rates.items():
        if groups and name in groups:
            top[groups[name]] = max(top.get(groups[name], 0.0), hz)
    return {
        name: round((top[groups[name]] if groups and name in groups else hz) * frame_bytes(name, mavlink_version), 1)
        for name, hz in rates.items()
    }


def predict(
    wanted: dict[str, float],
    mavlink_version: int,
    budget_bps: float,
    background_bps: float = 0.0,
    keep_hz: float = 5.0,
    groups: dict[str, int] | None = None,
) -> RatePrediction:
    """The highest common factor (in 2 % steps) by which the fast streams (above `keep_hz`) can be
    scaled so everything fits the budget; slow streams (GPS, barometer, health) keep their rate and
    no stream goes below `keep_hz`. `groups`: message → REQUEST_DATA_STREAM group (whole Hz)."""
    room = max(budget_bps - background_bps, 0.0)
    scale = 1.0
    while True:
        rates = rates_at_scale(wanted, scale, keep_hz, whole_hz=bool(groups))
        costs = stream_costs(rates, mavlink_version, groups)
        if sum(costs.values()) <= room or scale <= 0.02:
            return RatePrediction(scale, rates, costs, budget_bps, round(background_bps, 1))
        scale = round(scale - 0.02, 2)
