"""The real ArduPlane SITL (../shared/sitl): its 50 Hz scheduler loop refuses SET_MESSAGE_INTERVAL
above 0.8 × SCHED_LOOP_RATE = 40 Hz (COMMAND_ACK DENIED, then the STATUSTEXT "Requested rate for
message ID 27 too fast. Increase SCHED_LOOP_RATE" in two MAVLink 2 chunks). gcs must end with the
IMU messages at that maximum, every other message at its requested rate through
SET_MESSAGE_INTERVAL (the barometer at 5 Hz, not at the IMU's group rate), the reason in
/api/status, and the firmware version from AUTOPILOT_VERSION."""

from __future__ import annotations

import asyncio

import pytest
from live import running_station, served_api, wait_for
from test_sitl_copter import sitl_process

from gcs.runtime.streams import MESSAGE_IDS, StreamPlan

pytestmark = pytest.mark.slow

PLAN = StreamPlan(imu_hz=50.0, attitude_hz=25.0, gps_hz=5.0, aux_hz=5.0)
#: ArduPlane's largest accepted rate at its default SCHED_LOOP_RATE 50.
PLANE_MAX_HZ = 40.0


def at_rates(rows) -> bool:
    """Every planned message arriving within 15 % of the rate the vehicle accepted."""
    wanted = PLAN.for_autopilot("ArduPilot")
    if not all(name in rows and rows[name].accepted_hz for name in wanted):
        return False
    return all(abs(rows[name].achieved_hz - rows[name].accepted_hz) <= 0.15 * rows[name].accepted_hz for name in wanted)


@pytest.fixture
def plane(tmp_path):
    """ArduPlane SITL at real time in a scratch folder."""
    with sitl_process(tmp_path / "sitl", "arduplane", "plane", "plane.parm", 1) as port:
        yield port


@pytest.mark.timeout(240)
def test_arduplane_refused_imu_rate_ends_at_its_maximum_others_at_their_requested_rates(plane):
    """Measured (2026-12-02, 24 s): RAW_IMU and SCALED_IMU2 requested 50, accepted 40, achieved
    39.97 Hz; ATTITUDE and SIMSTATE 25 -> 24.93 Hz; GPS_RAW_INT, SCALED_PRESSURE, AHRS 5 -> 4.95 Hz."""

    async def scenario():
        async with running_station(f"tcp:127.0.0.1:{plane}", plan=PLAN, estimate=False) as station:
            await wait_for(lambda: station.streams.requested, 90, "stream requests")
            async with served_api(station) as api:
                # AHRS2 (the secondary attitude) starts only once the EKF is primary, after GPS lock
                await wait_for(lambda: at_rates(station.publish().streams.messages), 120, "every accepted rate")
                await wait_for(lambda: station.vehicle.firmware is not None, 30, "the firmware version")
                station.publish()
                return (await api.get("/api/status")).json()

    status = asyncio.run(scenario())
    streams = status["link"]["streams"]
    wanted = PLAN.for_autopilot("ArduPilot")
    summary = {n: (r["requested_hz"], r["accepted_hz"], r["achieved_hz"]) for n, r in streams.items()}
    print("requested, accepted, achieved Hz:", summary)
    for name, hz in wanted.items():
        row = streams[name]
        assert row["method"] == "SET_MESSAGE_INTERVAL", (name, row)
        expected = min(hz, PLANE_MAX_HZ)
        assert row["accepted_hz"] == expected, (name, row, summary)
        assert abs(row["achieved_hz"] - expected) <= 0.15 * expected, (name, row, summary)
        if hz > PLANE_MAX_HZ:
            text = f"Requested rate for message ID {MESSAGE_IDS[name]} too fast. Increase SCHED_LOOP_RATE"
            assert row["reason"] == f"DENIED at 50 Hz: {text}; accepted 40 Hz", row
        else:
            assert row["reason"] is None, row
    assert status["link"]["stream_method"] == "SET_MESSAGE_INTERVAL"
    assert "4.7.0-dev" in status["vehicle"]["firmware"], status["vehicle"]
