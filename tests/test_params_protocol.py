"""The parameter protocol client against the simulator's parameter server over real UDP sockets:
full downloads with lost packets in both encodings, typed values, verified writes, mismatches."""

from __future__ import annotations

import asyncio
import contextlib
import time

import pytest
from conftest import free_port
from live import running_sim, running_station

from gcs.mavlink.dialect import mavlink
from gcs.mavlink.params import ParamError, encode, format_value
from gcs.runtime.params import ParamMismatch, UnknownParam


@contextlib.asynccontextmanager
async def station_and_sim(profile: str, streams: bool = False, estimate: bool = False, **sim_kwargs):
    """A station connected over UDP to a simulated vehicle: (station, sim)."""
    port = free_port()
    async with running_station(f"udpin:127.0.0.1:{port}", estimate=estimate, request_streams=streams) as station:
        async with running_sim(f"udpout:127.0.0.1:{port}", profile=profile, **sim_kwargs) as sim:
            assert await station.link.wait_connected(10)
            yield station, sim


#: Download times measured by the tests, printed at the end of the session (-s) for the report.
FIGURES: dict[str, float] = {}


@pytest.fixture(scope="module", autouse=True)
def print_figures():
    yield
    for key, seconds in FIGURES.items():
        print(f"\nparameter download {key}: {seconds:.2f} s")


async def _download(profile: str, drop: float, streams: bool):
    async with station_and_sim(profile, streams, param_drop=drop, seed=3) as (station, sim):
        start = time.monotonic()
        table = await station.params.download(timeout=60)
        elapsed = time.monotonic() - start
        return table, sim, station.params.progress(), station.params.bytewise, elapsed


@pytest.mark.parametrize(
    "profile,drop", [("pixhawk", 0.0), ("pixhawk", 0.1), ("apm25", 0.0), ("apm25", 0.1), ("px4", 0.0), ("px4", 0.1)]
)
def test_full_download_is_exact_with_lost_packets(profile, drop):
    # apm25 runs with its streams requested, as over the radio in the field (MAVLink 1).
    table, sim, progress, bytewise, elapsed = asyncio.run(_download(profile, drop, streams=profile == "apm25"))
    truth = sim.params.as_dict()
    assert len(truth) >= 500
    assert {name: p.value for name, p in table.items()} == truth  # every name, every value, exactly
    assert bytewise == (profile == "px4")
    assert progress["state"] == "complete" and progress["received"] == len(truth) and progress["missing"] == []
    if drop:
        assert sim.param_server.dropped > 0.05 * len(truth)
        assert progress["read_requests"] >= len(truth) * 0.05  # the lost ones were asked for again
    FIGURES[f"{profile} drop {drop:.0%} ({len(truth)} params)"] = elapsed
    assert elapsed < 20


def test_px4_integers_are_typed_and_bytewise():
    async def scenario():
        async with station_and_sim("px4") as (station, sim):
            params = station.params
            autostart = await params.read("SYS_AUTOSTART")
            assert autostart.value == 4001 and isinstance(autostart.value, int)
            assert autostart.type == mavlink.MAV_PARAM_TYPE_INT32
            assert (await params.set("SYS_AUTOSTART", 4010)).value == 4010
            assert sim.params["SYS_AUTOSTART"] == 4010
            assert (await params.set("COM_FLTMODE1", -1)).value == -1  # a NaN pattern on the wire
            assert sim.params["COM_FLTMODE1"] == -1
            rate = await params.set("MC_ROLLRATE_P", 0.16)
            assert isinstance(rate.value, float) and sim.params["MC_ROLLRATE_P"] == rate.value
            with pytest.raises(ParamError, match="SYS_AUTOSTART is INT32: 4010.5 is not an integer"):
                await params.set("SYS_AUTOSTART", 4010.5)
            assert sim.params["SYS_AUTOSTART"] == 4010  # nothing sent

    asyncio.run(asyncio.wait_for(scenario(), 30))


def test_ardupilot_write_is_verified_and_logged():
    async def scenario():
        async with station_and_sim("apm25") as (station, sim):
            params = station.params
            stored = await params.set("RATE_RLL_P", 0.17, client="test")
            assert stored.value == sim.params["RATE_RLL_P"] == pytest.approx(0.17)
            assert params.table["RATE_RLL_P"].value == stored.value
            log = await params.set("LOG_BITMASK", 831)
            assert log.value == 831 and isinstance(log.value, int)
            assert not params.bytewise  # ArduPilot: integers as plain floats
            events = [e.as_dict() for e in station.events.recent if e.kind == "param"]
            assert events[0] | {"wall_time": 0, "host_time": 0} == {
                "wall_time": 0,
                "host_time": 0,
                "kind": "param",
                "client": "test",
                "name": "RATE_RLL_P",
                "old": pytest.approx(0.15),
                "new": stored.value,
                "asked": stored.value,
                "verified": True,
            }
            assert events[1]["name"] == "LOG_BITMASK" and events[1]["old"] == 830

    asyncio.run(asyncio.wait_for(scenario(), 30))


def test_a_value_the_vehicle_reports_changed_is_an_event():
    """A parameter the vehicle reports with a new value, whoever changed it (here the vehicle
    itself, as an autotune or a compass calibration does), is a "param value" event: the server
    pushes it to every page (a second Tuning tab showed it only at its next poll). One the same
    as before is none, so a download of the whole table makes no events."""

    async def scenario():
        async with station_and_sim("apm25") as (station, sim):
            params = station.params
            before = (await params.read("RATE_RLL_P")).value
            await params.read("RATE_PIT_P")
            sim.params["RATE_RLL_P"] = 0.16
            await params.read("RATE_RLL_P")
            return before, [e.as_dict() for e in station.events.recent if e.kind == "param value"]

    before, events = asyncio.run(asyncio.wait_for(scenario(), 30))
    assert [(e["client"], e["name"], e["old"], e["new"]) for e in events] == [
        ("vehicle", "RATE_RLL_P", before, pytest.approx(0.16))
    ]


def test_vehicle_storing_another_value_is_an_error_not_silence():
    async def scenario():
        async with station_and_sim("pixhawk", param_clamp={"ATC_RAT_RLL_P": 0.15}) as (station, sim):
            with pytest.raises(ParamMismatch) as caught:
                await station.params.set("ATC_RAT_RLL_P", 0.2, client="test")
            assert str(caught.value) == "ATC_RAT_RLL_P: vehicle stored 0.15, asked 0.2"
            assert sim.params["ATC_RAT_RLL_P"] == pytest.approx(0.15)
            (event,) = [e.data for e in station.events.recent if e.kind == "param"]
            assert event["verified"] is False and event["new"] == pytest.approx(0.15)
            assert event["asked"] == pytest.approx(0.2)

    asyncio.run(asyncio.wait_for(scenario(), 30))


def test_no_echo_is_a_timeout_naming_the_parameter():
    async def scenario():
        async with station_and_sim("pixhawk") as (station, sim):
            params = station.params
            params.reply_timeout = 0.3
            await params.read("AHRS_RP_P")
            sim.param_drop = 1.0  # every PARAM_VALUE lost from now on
            start = time.monotonic()
            with pytest.raises(ParamError, match="AHRS_RP_P: no echo after 3 writes × 0.3 s"):
                await params.set("AHRS_RP_P", 0.25)
            assert 0.8 < time.monotonic() - start < 2.0  # bounded: 3 × 0.3 s
            assert sim.params["AHRS_RP_P"] == pytest.approx(0.25)  # it did arrive; the log says unknown
            assert [e.data["verified"] for e in station.events.recent if e.kind == "param"] == [False]

    asyncio.run(asyncio.wait_for(scenario(), 30))


def test_incomplete_download_reports_what_is_missing():
    async def scenario():
        async with station_and_sim("apm25", param_drop=0.6, seed=1) as (station, sim):
            params = station.params
            params.reply_timeout, params.read_attempts, params.list_gap, params.window = 0.2, 1, 0.3, 64
            with pytest.raises(
                ParamError,
                match=r"parameter download incomplete \(each asked 1 times\): "
                r"\d+ of 501 missing, indices \d+",
            ):
                await params.download()
            progress = params.progress()
            assert progress["state"] == "incomplete" and progress["count"] == len(sim.params)
            assert 0 < len(progress["missing"]) <= 50 and not params.complete
            sim.param_drop = 0.0
            params.read_attempts = 5
            await params.download()
            assert params.complete
            with pytest.raises(UnknownParam, match="no parameter RATE_RLL_Q; did you mean RATE_RLL_"):
                await params.read("RATE_RLL_Q")

    asyncio.run(asyncio.wait_for(scenario(), 60))


def test_encoding_rules_name_what_is_wrong():
    with pytest.raises(ParamError, match=r"FRAME is INT8: 200 is outside \[-128, 127\]"):
        encode("FRAME", 200, mavlink.MAV_PARAM_TYPE_INT8, bytewise=False)
    with pytest.raises(ParamError, match="X: 2143289000 is a signalling-NaN bit pattern"):
        encode("X", 2143289000, mavlink.MAV_PARAM_TYPE_INT32, bytewise=True)
    with pytest.raises(ParamError, match="not a finite number"):
        encode("X", float("nan"), mavlink.MAV_PARAM_TYPE_REAL32, bytewise=False)
    assert encode("X", 0.1, mavlink.MAV_PARAM_TYPE_REAL32, bytewise=True)[1] == pytest.approx(0.1)
    assert format_value(encode("X", 0.135, mavlink.MAV_PARAM_TYPE_REAL32, False)[1]) == "0.135"
    assert format_value(830) == "830" and format_value(1e-5) == "1e-05"
