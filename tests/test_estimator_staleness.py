"""An estimator reads unreliable once its figures are stale: when the link is lost, and when no IMU
sample has arrived for longer than the window its reliability is judged over, though heartbeats
go on. Its comparison judges the rate over its last window of IMU samples, which stays as it was
when they stop (it read "reliable" for as long as the link stayed down). The real station and its
dashboard server, the simulator over UDP on loopback, `GET /api/status` as the page reads it."""

from __future__ import annotations

import asyncio

from live import running_sim, running_station, served_api, wait_for

from gcs.mavlink.dialect import mavlink
from gcs.runtime.link import LinkState

ESTIMATORS = {"dcm", "kf", "ekf"}


async def poll_status(api, predicate, timeout: float, what: str) -> dict:
    """GET /api/status until predicate(status) holds; AssertionError after `timeout` s."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while True:
        status = (await api.get("/api/status")).json()
        if predicate(status):
            return status
        if loop.time() > deadline:
            last = {name: (e["reliable"], e["reason"]) for name, e in status["estimators"].items()}
            raise AssertionError(f"timed out after {timeout} s waiting for {what}; last (reliable, reason): {last}")
        await asyncio.sleep(0.1)  # the poll's pace, as live.wait_for's


def all_reliable(status: dict) -> bool:
    estimators = status["estimators"]
    return set(estimators) == ESTIMATORS and all(e["reliable"] for e in estimators.values())


def none_reliable(status: dict) -> bool:
    return all(not e["reliable"] for e in status["estimators"].values())


def set_interval(station, message: str, hz: float) -> None:
    """SET_MESSAGE_INTERVAL to the vehicle (sysid 1) over the station's link; hz <= 0: off."""
    interval = 1e6 / hz if hz > 0 else -1
    msg_id = getattr(mavlink, f"MAVLINK_MSG_ID_{message}")
    command = mavlink.MAV_CMD_SET_MESSAGE_INTERVAL
    station.link.send(mavlink.MAVLink_command_long_message(1, 1, command, 0, msg_id, interval, 0, 0, 0, 0, 0))


def test_lost_link_makes_every_estimator_unreliable(udp_port):
    async def scenario() -> dict:
        async with running_station(f"udpin:127.0.0.1:{udp_port}", heartbeat_timeout=1.0) as station:
            async with served_api(station) as api:
                async with running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad"):
                    await poll_status(api, all_reliable, 60, "every estimator reliable at 50 Hz of RAW_IMU")
                # the vehicle is gone: no heartbeat, no IMU
                await wait_for(lambda: station.link.state == LinkState.LOST, 10, "the link lost")
                return await poll_status(api, none_reliable, 5, "every estimator unreliable after the link was lost")

    status = asyncio.run(scenario())
    assert status["link"]["state"] == "lost"
    for name, e in status["estimators"].items():
        assert e["reason"].startswith("link lost: no IMU for "), f"{name}: {e['reason']!r}"
        assert e["imu_rate_hz"] > 45, f"{name}: the rate of its last window stays (that is why it is stale)"


def test_silent_imu_with_heartbeats_makes_every_estimator_unreliable(udp_port):
    async def scenario() -> tuple[dict, float]:
        # no stream negotiation: the test asks for the streams itself, and stops the IMU with no
        # requester asking for it again
        async with running_station(f"udpin:127.0.0.1:{udp_port}", request_streams=False) as station:
            window = station.estimation.pipeline.comparisons["dcm"].window  # the reliability's window
            async with (
                served_api(station) as api,
                running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad"),
            ):
                assert await station.link.wait_connected(10), "no heartbeat"
                set_interval(station, "ATTITUDE", 50.0)
                set_interval(station, "RAW_IMU", 50.0)
                await poll_status(api, all_reliable, 60, "every estimator reliable at 50 Hz of RAW_IMU")
                set_interval(station, "RAW_IMU", 0.0)
                silent = f"every estimator unreliable after {window} s without IMU"
                status = await poll_status(api, none_reliable, window + 5, silent)
                assert station.link.state == LinkState.CONNECTED, "heartbeats went on"
                return status, window

    status, window = asyncio.run(scenario())
    assert status["link"]["state"] == "connected"
    for name, e in status["estimators"].items():
        assert e["reason"].startswith("no IMU for "), f"{name}: {e['reason']!r}"
        assert f"longer than the {window:g} s window" in e["reason"], f"{name}: {e['reason']!r}"
