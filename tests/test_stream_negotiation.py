"""Stream negotiation per message against the simulator refusing RAW_IMU above 40 Hz as ArduPlane
does (DENIED + "Requested rate for message ID 27 too fast. Increase SCHED_LOOP_RATE"), over real
UDP, with the status read from a real uvicorn: RAW_IMU ends at its maximum, every other message at
its requested rate through SET_MESSAGE_INTERVAL, and the vehicle's reason is in /api/status."""

from __future__ import annotations

import asyncio

from live import other_system, running_sim, running_station, served_api, wait_for

from gcs.commands.status import format_report
from gcs.mavlink.dialect import mavlink
from gcs.runtime.link import LinkState
from gcs.runtime.streams import NOT_SENT

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


def test_streams_that_stopped_while_others_flow_are_asked_again(udp_port):
    """A quick reboot, then another ground station asks the new boot for the barometer alone: the
    streams accepted before, which had arrived and have stopped, are asked for again, although not
    every stream is silent (one never seen at all would be taken as lacking, and left alone)."""

    async def scenario():
        address = f"udpout:127.0.0.1:{udp_port}"
        async with running_station(f"udpin:127.0.0.1:{udp_port}", estimate=False) as station:
            station.streams.check_interval = 0.5
            station.streams.retry_interval = station.link.stats.window + 5.0
            async with running_sim(address, profile="pixhawk"):
                rates = station.link.stats.rates
                await wait_for(lambda: rates().get("ATTITUDE", 0) > 0, 30, "the first boot's ATTITUDE arriving")
            async with running_sim(address, profile="pixhawk") as second:
                other_gcs = mavlink.MAVLink_command_long_message(
                    1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                    mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE, 200_000, 0, 0, 0, 0, 0,
                )  # fmt: skip
                # at once, while the old boot's packets are still in the rate window: every stream
                # silent (the quick-reboot rule) never happens
                await wait_for(lambda: second.received.get("HEARTBEAT", 0) > 0, 30, "the station heard by the new boot")
                station.link.send(other_gcs)
                await wait_for(lambda: "SCALED_PRESSURE" in second.stream_rates(), 30, "the barometer alone")
                assert "ATTITUDE" not in second.stream_rates()
                await wait_for(lambda: second.stream_rates().get("ATTITUDE", 0) > 0, 60, "ATTITUDE asked again")
                return station.streams.requests_sent

    assert asyncio.run(scenario()) > 0


def test_a_stream_that_stays_starved_is_asked_ever_more_rarely(udp_port):
    """Another ground station slows ATTITUDE to 1 Hz and the vehicle refuses anything faster from
    now on: the station's re-requests (each refused) come after 1, 2, then 4 retry intervals, not
    once every interval for good over what may be a slow radio."""

    async def scenario():
        async with (
            running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk") as sim,
            running_station(f"udpin:127.0.0.1:{udp_port}", estimate=False) as station,
        ):
            streams = station.streams
            streams.check_interval, streams.retry_interval = 0.25, 2.0
            await wait_for(lambda: settled(station, {"ATTITUDE": 50.0}), 30, "ATTITUDE at 50 Hz")
            sim.interval_limits["ATTITUDE"] = 1.0
            other_gcs = mavlink.MAVLink_command_long_message(
                1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, mavlink.MAVLINK_MSG_ID_ATTITUDE, 1_000_000, 0, 0, 0, 0, 0
            )
            station.link.send(other_gcs)
            await wait_for(lambda: sim.stream_rates().get("ATTITUDE") == 1.0, 30, "ATTITUDE slowed to 1 Hz")
            asked = [streams._last_request["ATTITUDE"]]  # the other GCS's request went out as ours

            def asked_again(times: int) -> bool:
                if streams._last_request["ATTITUDE"] != asked[-1]:
                    asked.append(streams._last_request["ATTITUDE"])
                return len(asked) > times

            await wait_for(lambda: asked_again(3), 60, "three re-requests of ATTITUDE")
            return asked, sim.stream_rates()["ATTITUDE"], streams.negotiated["ATTITUDE"].ack

    asked, rate, ack = asyncio.run(scenario())
    gaps = [b - a for a, b in zip(asked[1:], asked[2:], strict=False)]
    print(f"\nre-requests of ATTITUDE {gaps} s apart (retry_interval 2 s)")
    assert rate == 1.0 and ack == "DENIED"  # refused each time: still starved
    assert gaps[0] >= 2 * 2.0 - 0.1 and gaps[1] >= 4 * 2.0 - 0.1, gaps


def test_a_message_the_vehicle_does_not_have_says_so_where_it_shows_0_hz(udp_port):
    """Found by auditing an APM 2.5 behind a 57600 radio: `gcs status` listed SCALED_IMU2 and AHRS2
    "accepted 19.0 Hz achieved 0.0 Hz" with no word why (REQUEST_DATA_STREAM asks by group and
    nothing acknowledges it; the APM 2.5 has one IMU): a link fault to the eye. Once the retry
    interval has passed with none of it, the row says the vehicle does not send it; never a
    message that flows."""

    async def scenario():
        async with (
            running_sim(f"udpout:127.0.0.1:{udp_port}", profile="apm25"),
            running_station(f"udpin:127.0.0.1:{udp_port}", estimate=False) as station,
            served_api(station) as api,
        ):
            streams = station.streams
            streams.check_interval, streams.retry_interval = 0.25, 2.0

            def told() -> bool:
                rows = station.publish().streams.messages
                return "SCALED_IMU2" in rows and rows["SCALED_IMU2"].reason == NOT_SENT

            await wait_for(told, 60, "SCALED_IMU2 said to be absent")
            await wait_for(lambda: settled(station, {"RAW_IMU": 50.0}), 30, "RAW_IMU at 50 Hz")
            return (await api.get("/api/status")).json()["link"]["streams"], format_report(station.publish())

    rows, printed = asyncio.run(scenario())
    assert rows["SCALED_IMU2"]["achieved_hz"] == 0.0 and rows["SCALED_IMU2"]["reason"] == NOT_SENT, rows
    assert rows["RAW_IMU"]["achieved_hz"] > 0 and rows["RAW_IMU"]["reason"] != NOT_SENT, rows
    assert rows["SCALED_IMU2"]["method"] == "REQUEST_DATA_STREAM"
    assert NOT_SENT in printed


def test_ekf_status_report_is_asked_of_an_ardupilot_with_an_ekf_not_of_an_apm25(udp_port):
    """gcs asks for EKF_STATUS_REPORT (the onboard/onboard-unready rule's input) at 1 Hz on an
    ArduPilot 4.x, accepted by SET_MESSAGE_INTERVAL; the APM 2.5 (MAVLink 1, DCM only) has none to
    send, and gets neither a request nor a stream or radio row for it: read once its SCALED_IMU2,
    which it lacks too, is told absent (NOT_SENT), as EKF_STATUS_REPORT would be if asked."""

    async def run(profile: str, port: int, ready):
        async with (
            running_sim(f"udpout:127.0.0.1:{port}", profile=profile),
            running_station(f"udpin:127.0.0.1:{port}", estimate=False) as station,
        ):
            station.streams.check_interval, station.streams.retry_interval = 0.25, 2.0
            await wait_for(lambda: ready(station.publish().streams.messages), 60, f"the {profile}'s streams")
            snapshot = station.publish()
            radio = snapshot.radio.streams if snapshot.radio is not None else {}
            return snapshot.streams.messages, radio, station.vehicle.ekf_flags

    def accepted(name: str):
        return lambda rows: name in rows and rows[name].accepted_hz and rows[name].achieved_hz > 0

    def told_absent(name: str):
        return lambda rows: name in rows and rows[name].reason == NOT_SENT

    pixhawk, _, flags = asyncio.run(run("pixhawk", udp_port, accepted("EKF_STATUS_REPORT")))
    row = pixhawk["EKF_STATUS_REPORT"]
    assert (row.method, row.ack, row.accepted_hz, row.reason) == ("SET_MESSAGE_INTERVAL", "ACCEPTED", 1.0, None), row
    assert "ATTITUDE" in flags, flags
    apm25, radio, _ = asyncio.run(run("apm25", udp_port, told_absent("SCALED_IMU2")))
    assert "RAW_IMU" in apm25 and "EKF_STATUS_REPORT" not in apm25, apm25
    assert "EKF_STATUS_REPORT" not in radio, radio


def test_acks_from_another_system_are_not_the_vehicles_answer(udp_port):
    """Another system on the link (a second ground station, a companion, a hostile peer: udpin
    answers any sender) answers each SET_MESSAGE_INTERVAL the station sends with a refusal, at
    once: the station waits for its vehicle's own answer and every stream keeps the rate the
    vehicle accepted."""

    def refuse(msg, mav):
        if msg.get_type() == "COMMAND_LONG" and msg.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            return [mav.command_ack_encode(msg.command, mavlink.MAV_RESULT_DENIED)]
        return []

    async def scenario():
        async with running_station(f"udpin:127.0.0.1:{udp_port}", estimate=False) as station:
            with other_system(udp_port, refuse) as refused:
                await wait_for(lambda: station.link.stats.framing.packets > 0, 10, "the other system heard")
                async with running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk"):
                    await wait_for(lambda: station.streams.requested, 30, "stream requests")
                    return station.publish().streams, len(refused)

    streams, refused = asyncio.run(scenario())
    assert refused  # the other system got the station's commands and refused them
    for name, hz in REQUESTED.items():
        row = streams.messages[name]
        assert row.method == "SET_MESSAGE_INTERVAL" and row.accepted_hz == hz and row.reason is None, (name, row)
