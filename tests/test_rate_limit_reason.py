"""An estimator unreliable for a too-low IMU rate says what holds the rate down, where the station
knows it. The reason's advice, "request RAW_IMU at 50 Hz or more", read as if nobody had, while
the station had asked for 50 Hz and the vehicle refused it (ArduPlane: "Increase
SCHED_LOOP_RATE", found on the real ArduPlane SITL), or had itself asked for 19 Hz to fit an APM
2.5's 57600 radio. The simulator over real UDP, /api/status from a real uvicorn."""

from __future__ import annotations

import asyncio

from live import running_sim, running_station, served_api, wait_for

from gcs.sim import SimVehicle
from gcs.sim.radio import fit_radio


async def unreliable_reason(station, wanted: str) -> tuple[str, float]:
    """The dcm's reason and IMU rate in /api/status once the rate is measured (10 Hz or more)
    and the reason holds `wanted`."""
    async with served_api(station) as api:

        def told() -> bool:
            e = station.publish().estimation
            dcm = None if e is None else e.estimators["dcm"]
            return dcm is not None and dcm.imu_rate_hz >= 10 and wanted in dcm.reason

        await wait_for(told, 60, f"an IMU-rate reason naming {wanted!r}")
        dcm = (await api.get("/api/status")).json()["estimators"]["dcm"]
        return dcm["reason"], dcm["imu_rate_hz"]


def test_a_refused_imu_rate_is_named_in_the_estimators_reason(udp_port):
    async def scenario() -> tuple[str, float]:
        async with (
            running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", interval_limits={"RAW_IMU": 40.0}),
            running_station(f"udpin:127.0.0.1:{udp_port}") as station,
        ):
            return await unreliable_reason(station, "SCHED_LOOP_RATE")

    reason, rate = asyncio.run(scenario())
    assert reason.startswith("raw IMU at ") and "Hz, below the 50 Hz needed" in reason and rate <= 40.5, reason
    assert "(asked for at 50 Hz: DENIED at 50 Hz: Requested rate for message ID 27 too fast." in reason, reason


def test_an_imu_rate_fitted_to_the_radio_is_named_in_the_estimators_reason(udp_port):
    async def scenario() -> tuple[str, float]:
        async with running_station(f"udpin:127.0.0.1:{udp_port}") as station:
            sim = SimVehicle(profile="apm25", script="bench")
            fit_radio(sim, 57600)
            task = asyncio.create_task(sim.run(f"udpout:127.0.0.1:{udp_port}"))
            try:
                return await unreliable_reason(station, "radio")
            finally:
                task.cancel()
                await asyncio.gather(task, return_exceptions=True)

    reason, rate = asyncio.run(scenario())
    assert reason.startswith("raw IMU at ") and "Hz, below the 50 Hz needed" in reason and rate < 47.5, reason
    assert "to fit the radio's budget; over USB it can come at 50 Hz)" in reason, reason
