"""Tuning profiles and the TuningSession against the simulator: refusals with clear messages,
rate limits, verified writes in the event log, revert to the exact pre-flight snapshot."""

from __future__ import annotations

import asyncio
import dataclasses

import pytest
from test_params_protocol import station_and_sim

from gcs.runtime.params import ParamMismatch, ParamTimeout
from gcs.runtime.tuning import (
    GLOBAL_PER_SECOND,
    PER_PARAM_INTERVAL,
    ProfileError,
    RateLimited,
    RateLimiter,
    TuningRefused,
    available_profiles,
    detect_profile,
    load_profile,
    open_session,
    parse_profile,
)
from gcs.sim import param_tables

FIRMWARE_TABLES = {
    "arducopter-3.2": param_tables.arducopter_32,
    "arducopter-4": param_tables.arducopter_4,
    "px4": param_tables.px4_115,
}


@pytest.mark.parametrize("name", sorted(FIRMWARE_TABLES))
def test_shipped_profiles_fit_their_firmware(name):
    profile = load_profile(name)
    defaults = {row[0]: row[1] for row in FIRMWARE_TABLES[name]()}
    assert len(profile.params) >= 10
    for spec in profile.params.values():
        assert spec.name in defaults, f"{name}: {spec.name} is not a parameter of that firmware"
        assert spec.min <= defaults[spec.name] <= spec.max, f"{name}: stock {spec.name} outside the bounds"
        assert 0 < spec.step < spec.max - spec.min and spec.meaning
    assert detect_profile(defaults, profile.autopilot).name == name
    assert available_profiles() == sorted(FIRMWARE_TABLES)


def test_required_gains_are_in_the_profiles():
    assert {
        "RATE_RLL_P",
        "RATE_PIT_P",
        "RATE_YAW_P",
        "RATE_RLL_I",
        "STB_RLL_P",
        "STB_PIT_P",
        "STB_YAW_P",
        "AHRS_RP_P",
        "AHRS_YAW_P",
    } <= set(load_profile("arducopter-3.2").params)
    assert {f"ATC_RAT_{axis}_{term}" for axis in ("RLL", "PIT") for term in "PID"} | {
        "ATC_RAT_YAW_P",
        "ATC_RAT_YAW_I",
        "ATC_ANG_RLL_P",
        "ATC_ANG_PIT_P",
        "ATC_ANG_YAW_P",
        "AHRS_RP_P",
        "AHRS_YAW_P",
    } <= set(load_profile("arducopter-4").params)
    assert {f"MC_{axis}RATE_{term}" for axis in ("ROLL", "PITCH") for term in "PID"} | {
        "MC_YAWRATE_P",
        "MC_ROLL_P",
        "MC_PITCH_P",
        "MC_YAW_P",
    } <= set(load_profile("px4").params)


def test_bad_profiles_are_named():
    with pytest.raises(ProfileError, match=r"x.toml: params.A: min 2.0 is not below max 1.0"):
        parse_profile(
            'name="x"\nautopilot="PX4"\ndetect="A"\n[params.A]\nmin=2\nmax=1\nstep=0.1\nmeaning="m"', "x.toml"
        )
    with pytest.raises(ProfileError, match="x.toml: params.A: missing meaning"):
        parse_profile('name="x"\nautopilot="PX4"\ndetect="A"\n[params.A]\nmin=0\nmax=1\nstep=0.1', "x.toml")
    with pytest.raises(ProfileError, match="unknown tuning profile 'ardu'; shipped: arducopter-3.2"):
        load_profile("ardu")


def test_profile_refusals_name_the_rule_and_the_numbers():
    profile = load_profile("arducopter-4")
    with pytest.raises(TuningRefused, match=r"ATC_RAT_RLL_P = 0.6 is outside the allowed range \[0.01, 0.5\]"):
        profile.check("ATC_RAT_RLL_P", 0.6, 0.45)
    with pytest.raises(
        TuningRefused,
        match=r"ATC_RAT_RLL_P: 0.135 -> 0.2 changes it by 0.065, more than the "
        r"largest step 0.02 allowed per write",
    ):
        profile.check("ATC_RAT_RLL_P", 0.2, 0.135)
    with pytest.raises(TuningRefused, match="FRAME_CLASS is not in the tuning profile arducopter-4"):
        profile.check("FRAME_CLASS", 1, 1)
    assert profile.check("ATC_RAT_RLL_P", 0.155, 0.135).name == "ATC_RAT_RLL_P"  # exactly one step


def test_rate_limiter_numbers():
    now = [0.0]
    limiter = RateLimiter(clock=lambda: now[0])
    limiter.take("A")
    with pytest.raises(RateLimited, match=r"A was written 0.10 s ago; wait 0.10 s \(at least 0.2 s between"):
        now[0] = 0.1
        limiter.take("A")
    for i, name in enumerate("BCDE"):
        now[0] = 0.1 + 0.01 * i
        limiter.take(name)
    now[0] = 0.5
    with pytest.raises(RateLimited, match=r"5 writes in the last second already; wait 0.50 s"):
        limiter.take("F")
    now[0] = 1.0
    limiter.take("F")
    assert (PER_PARAM_INTERVAL, GLOBAL_PER_SECOND) == (0.2, 5)


def test_session_refuses_writes_audits_them_and_reverts_exactly():
    async def scenario():
        async with station_and_sim("pixhawk", param_drop=0.1, seed=7, param_clamp={"ATC_RAT_PIT_P": 0.14}) as (
            station,
            sim,
        ):
            session = await open_session(station.params)
            assert session.profile.name == "arducopter-4" and station.params.complete  # despite 10 % dropped
            sim.param_drop = 0.0  # from here on the rules are under test, not retries (their own tests)
            # the limiter's clock moves only when the test says: a write's round trip, however long a
            # loaded machine makes it, never lets the interval pass, nor does the test wait it out
            now = [0.0]
            session.limiter.clock = lambda: now[0]
            before = sim.params.as_dict()
            assert session.preflight["AHRS_RP_P"] == before["AHRS_RP_P"]

            with pytest.raises(TuningRefused, match="outside the allowed range"):
                await session.set("ATC_RAT_RLL_P", 0.9, "test")
            with pytest.raises(TuningRefused, match="more than the largest step 0.02"):
                await session.set("ATC_RAT_RLL_P", 0.2, "test")
            with pytest.raises(TuningRefused, match="SYSID_THISMAV is not in the tuning profile"):
                await session.set("SYSID_THISMAV", 2, "test")
            assert sim.params.as_dict() == before  # nothing refused reached the vehicle

            await session.set("ATC_RAT_RLL_P", 0.15, "api:10.0.0.2")
            with pytest.raises(RateLimited):
                await session.set("ATC_RAT_RLL_P", 0.16, "api:10.0.0.2")
            await session.set("AHRS_RP_P", 0.25, "viser")
            await session.set("AHRS_YAW_P", 0.15, "viser")
            with pytest.raises(ParamMismatch, match="ATC_RAT_PIT_P: vehicle stored 0.14, asked 0.15"):
                await session.set("ATC_RAT_PIT_P", 0.15, "test")
            now[0] += PER_PARAM_INTERVAL  # ATC_RAT_RLL_P's interval has passed
            await session.set("ATC_RAT_RLL_P", 0.165, "api:10.0.0.2")
            assert sim.params["ATC_RAT_RLL_P"] == pytest.approx(0.165)
            assert sim.autopilot.secondary.kp == pytest.approx(0.25)  # the DCM took the new gain
            rows = {row.name: dataclasses.asdict(row) for row in session.rows()}
            assert rows["AHRS_RP_P"]["changed"] and rows["AHRS_RP_P"]["current"] == pytest.approx(0.25)
            assert rows["AHRS_RP_P"]["preflight"] == pytest.approx(0.2) and not rows["ATC_ANG_RLL_P"]["changed"]

            restored = await session.revert("test")
            assert {p.name for p in restored} == {"ATC_RAT_RLL_P", "AHRS_RP_P", "AHRS_YAW_P", "ATC_RAT_PIT_P"}
            assert sim.params.as_dict() == before  # exactly the pre-flight table
            assert not any(row.changed for row in session.rows())

            writes = [e.as_dict() for e in station.events.recent if e.kind == "param"]
            assert [(w["name"], w["client"], w["verified"]) for w in writes] == [
                ("ATC_RAT_RLL_P", "api:10.0.0.2", True),
                ("AHRS_RP_P", "viser", True),
                ("AHRS_YAW_P", "viser", True),
                ("ATC_RAT_PIT_P", "test", False),
                ("ATC_RAT_RLL_P", "api:10.0.0.2", True),
                *((name, "test", True) for name in ("ATC_RAT_RLL_P", "ATC_RAT_PIT_P", "AHRS_RP_P", "AHRS_YAW_P")),
            ]  # revert: in profile order
            assert all(w["wall_time"] > 0 and "old" in w and "new" in w for w in writes)
            assert writes[0]["old"] == before["ATC_RAT_RLL_P"]

    asyncio.run(asyncio.wait_for(scenario(), 60))


def test_a_write_without_echo_is_unknown_until_the_vehicle_says():
    """The vehicle takes a write whose echo is lost: the row is `changed: None` (not "unchanged",
    which it was, with the new value on the vehicle) until a PARAM_VALUE of it arrives, and a
    revert writes it back."""

    async def scenario():
        async with station_and_sim("pixhawk") as (station, sim):
            session = await open_session(station.params)
            start = sim.params["ATC_RAT_RLL_P"]
            sim.param_drop = 1.0
            with pytest.raises(ParamTimeout, match="the value on the vehicle is unknown"):
                await session.set("ATC_RAT_RLL_P", 0.145, "test")
            assert sim.params["ATC_RAT_RLL_P"] == pytest.approx(0.145)
            row = next(r for r in session.rows() if r.name == "ATC_RAT_RLL_P")
            assert row.changed is None and row.current == pytest.approx(start), row
            sim.param_drop = 0.0
            await station.params.read("ATC_RAT_RLL_P")  # the vehicle's word, by any PARAM_VALUE
            row = next(r for r in session.rows() if r.name == "ATC_RAT_RLL_P")
            assert row.changed is True and row.current == pytest.approx(0.145), row
            sim.param_drop = 1.0
            with pytest.raises(ParamTimeout):
                await session.revert("test")
            assert next(r for r in session.rows() if r.name == "ATC_RAT_RLL_P").changed is None
            sim.param_drop = 0.0
            assert [p.name for p in await session.revert("test")] == ["ATC_RAT_RLL_P"]
            assert sim.params["ATC_RAT_RLL_P"] == pytest.approx(start)
            assert next(r for r in session.rows() if r.name == "ATC_RAT_RLL_P").changed is False

    asyncio.run(asyncio.wait_for(scenario(), 60))


def test_the_step_after_a_write_without_echo_is_from_the_vehicles_value():
    """After a write the vehicle took without echo (0.135 -> 0.155), the next write's step is
    measured from what the vehicle holds, read from it, not from the table's 0.135: 0.115 was
    allowed, moving the vehicle's gain by 0.04, twice the largest step per write."""

    async def scenario():
        async with station_and_sim("pixhawk") as (station, sim):
            session = await open_session(station.params)
            start = sim.params["ATC_RAT_RLL_P"]
            up, down = round(start + 0.02, 4), round(start - 0.02, 4)
            sim.param_drop = 1.0
            with pytest.raises(ParamTimeout):
                await session.set("ATC_RAT_RLL_P", up, "test")
            sim.param_drop = 0.0
            assert sim.params["ATC_RAT_RLL_P"] == pytest.approx(up)
            with pytest.raises(TuningRefused, match=r"0.155 -> 0.115 changes it by 0.04, more than the largest step"):
                await session.set("ATC_RAT_RLL_P", down, "test")
            assert sim.params["ATC_RAT_RLL_P"] == pytest.approx(up)
            row = next(r for r in session.rows() if r.name == "ATC_RAT_RLL_P")
            assert row.changed is True and row.current == pytest.approx(up)  # the read told the page too

    asyncio.run(asyncio.wait_for(scenario(), 60))
