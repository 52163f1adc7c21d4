"""A simulated flight written straight to a .tlog, as fast as the CPU allows (no link, no
pacing): test and benchmark flights of any length with known truth (SIMSTATE)."""

from __future__ import annotations

from pathlib import Path

from gcs.mavlink.dialect import Encoder, mavlink
from gcs.mavlink.tlog import tlog_record
from gcs.sim.vehicle import SimVehicle

BASE_US = 1_700_000_000_000_000


def write_tlog(
    path: str | Path, seconds: float, profile: str = "pixhawk", script: str = "quad", seed: int = 1, rate_hz: int = 50
) -> Path:
    """Every stream asked at rate_hz (REQUEST_DATA_STREAM), `seconds` of vehicle time stepped at
    rate_hz; written to a temporary name and renamed, so a cut run leaves no partial .tlog."""
    sim = SimVehicle(profile=profile, script=script, seed=seed)
    sim.handle_bytes(
        Encoder(255, 190).encode(
            mavlink.MAVLink_request_data_stream_message(1, 1, mavlink.MAV_DATA_STREAM_ALL, rate_hz, 1)
        )
    )
    target = Path(path)
    partial = target.with_name(target.name + ".partial")
    with open(partial, "wb") as fh:
        for k in range(1, int(seconds * rate_hz) + 1):
            t = k / rate_hz
            fh.write(b"".join(tlog_record(BASE_US + int(t * 1e6) & ~3, p) for p in sim.advance(t)))
    partial.rename(target)
    return target


def fly_flight_logs(sim: SimVehicle, seconds: list[float]) -> None:
    """Flights flown before `sim` boots, one per entry (s, vehicle time), each by a vehicle of the
    same profile and script (seed + k + 1), as fast as the CPU allows: their onboard logs become
    sim's logs 1..N, the flight `sim` then flies being the next."""
    for k, duration in enumerate(seconds):
        earlier = SimVehicle(profile=sim.profile.name, script=sim.script.name, seed=sim.seed + k + 1, home=sim.home)
        for step in range(1, int(duration) + 1):
            earlier.advance(float(step))
        earlier.advance(duration)
        earlier.logs.close_current()
        sim.logs.add(earlier.logs.finished[0])
