"""Stream negotiation per message against the simulator refusing RAW_IMU above 40 Hz as ArduPlane
does (DENIED + "Requested rate for message ID 27 too fast. Increase SCHED_LOOP_RATE"), over real
UDP, with the status read from a real uvicorn: RAW_IMU ends at its maximum, every other message at
its requested rate through SET_MESSAGE_INTERVAL, and the vehicle's reason is in /api/status."""

from __future__ import annotations

import asyncio

from live import running_sim, running_station, served_api, wait_for

from gcs.commands.status import format_report
from gcs.runtime.link import LinkState

REQUESTED = {"RAW_IMU": 50.0, "SCALED_IMU2": 50.0, "ATTITUDE": 50.0, "AHRS2": 50.0, "SCALED_PRESSURE": 5.0}


def settled(station, expected: dict[str, float]) -> bool:
    """Every expected stream arrives within 10 % of its rate over the link's rate window (the
    assertions after the wait say which one missed, if the deadline passes)."""
    rates = station.link.stats.rates()
    return all(abs(rates.get(name, 0.0) - hz) <= 0.1 * hz for name, hz in expected.items())


def test_refused_raw_imu_rate_is_lowered_to_the_vehicles_limit_others_keep_theirs(udp_port):
    async def scenario():
        async with (
            running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", interval_limits={"RAW_IMU": 40.0}) as sim,
            running_station(f"udpin:127.0.0.1:{udp_port}", estimate=False) as station,
        ):
            await wait_for(lambda: station.streams.requested, 30, "stream requests")
            async with served_api(station) as api:
                await wait_for(
                    lambda: (
                        (rows := station.snapshot.streams.messages)
                        and rows["RAW_IMU"].achieved_hz > 30
                        and rows["SCALED_PRESSURE"].achieved_hz > 0
                    ),
                    30,
                    "a snapshot with achieved rates",
                )
                expected = {**REQUESTED, "RAW_IMU": 40.0}  # what the vehicle accepted
                await wait_for(lambda: settled(station, expected), 30, "the accepted rates achieved")
                station.publish()
                status = (await api.get("/api/status")).json()
            return status, dict(sim.stream_rates()), format_report(station.snapshot)

    status, vehicle_rates, report = asyncio.run(scenario())
    streams = status["link"]["streams"]
    raw = streams["RAW_IMU"]
    assert raw["requested_hz"] == 50 and raw["accepted_hz"] == 40 and raw["method"] == "SET_MESSAGE_INTERVAL"
    assert raw["reason"] == (
        "DENIED at 50 Hz: Requested rate for message ID 27 too fast. Increase SCHED_LOOP_RATE; accepted 40 Hz"
    )
    assert abs(raw["achieved_hz"] - 40) <= 4, raw
    assert vehicle_rates["RAW_IMU"] == 40
    for name, hz in REQUESTED.items():
        if name == "RAW_IMU":
            continue
        row = streams[name]
        assert row["method"] == "SET_MESSAGE_INTERVAL" and row["accepted_hz"] == hz and row["reason"] is None, row
        assert abs(row["achieved_hz"] - hz) <= 0.1 * hz, (name, row)
        assert vehicle_rates[name] == hz  # the barometer at 5 Hz, not at RAW_IMU's group rate
    assert status["link"]["stream_method"] == "SET_MESSAGE_INTERVAL"
    (line,) = [line.split() for line in report.splitlines() if line.startswith("  RAW_IMU ")]
    assert line[line.index("accepted") + 1] == "40.0" and "too fast" in report


BARO_NEVER = {"SCALED_PRESSURE": 0.5}  # below the lowest step-down rate (1 Hz)


def test_message_refused_at_every_rate_alone_falls_back_to_its_group(udp_port):
    """SCALED_PRESSURE refused even at 1 Hz: it alone goes to REQUEST_DATA_STREAM (RAW_SENSORS at
    5 Hz), and its group-mates RAW_IMU and SCALED_IMU2 are asked for again, so they stay at 50 Hz."""

    async def scenario():
        async with (
            running_sim(
                f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", interval_limits={"SCALED_PRESSURE": 0.5}
            ) as sim,
            running_station(f"udpin:127.0.0.1:{udp_port}", estimate=False) as station,
        ):
            await wait_for(lambda: station.streams.requested, 30, "stream requests")
            expected = {"RAW_IMU": 50.0, "SCALED_IMU2": 50.0, "SCALED_PRESSURE": 5.0}
            await wait_for(lambda: settled(station, expected), 30, "the group's rates achieved")
            return station.publish().streams, dict(sim.stream_rates())

    streams, vehicle_rates = asyncio.run(scenario())
    baro = streams.messages["SCALED_PRESSURE"]
    assert baro.method == "REQUEST_DATA_STREAM" and baro.accepted_hz == 5.0
    assert baro.reason.startswith("DENIED at 1 Hz: Requested rate for message ID 29 too fast")
    assert abs(baro.achieved_hz - 5.0) <= 0.5
    assert streams.method == "mixed"
    for name in ("RAW_IMU", "SCALED_IMU2"):
        row = streams.messages[name]
        assert row.method == "SET_MESSAGE_INTERVAL" and vehicle_rates[name] == 50.0, (name, row)
        assert abs(row.achieved_hz - 50.0) <= 5.0, (name, row)


def test_a_vehicle_that_forgot_its_streams_is_asked_again(udp_port):
    """A reboot quicker than the heartbeat timeout: the link never goes lost and the new boot
    (ArduPilot: nothing streamed until asked) sends only heartbeats, none with a boot time that
    would show the reboot. The station asks again once every accepted stream has gone silent."""

    async def scenario():
        address = f"udpout:127.0.0.1:{udp_port}"
        async with running_station(f"udpin:127.0.0.1:{udp_port}", estimate=False) as station:
            # checked often; a retry only once the old boot's packets have left the rate window,
            # so the rule for a stream far below its rate (0 < achieved < half) cannot fire
            station.streams.check_interval = 0.5
            station.streams.retry_interval = station.link.stats.window + 5.0
            states = []
            station.link.state_changed.connect(lambda old, new: states.append(new))
            async with running_sim(address, profile="pixhawk") as first:
                await wait_for(lambda: first.stream_rates().get("ATTITUDE", 0) > 0, 30, "the first boot's streams")
            async with running_sim(address, profile="pixhawk") as second:
                assert "ATTITUDE" not in second.stream_rates()
                await wait_for(lambda: second.stream_rates().get("ATTITUDE", 0) > 0, 60, "the second boot asked again")
            return states

    states = asyncio.run(scenario())
    assert LinkState.LOST not in states, states
