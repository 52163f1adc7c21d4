"""The simulated vehicle's parameter table and the MAVLink parameter protocol, both encodings."""

from __future__ import annotations

import struct

import pytest

from gcs.mavlink.dialect import mavlink
from gcs.sim import SensorFaults, SimVehicle
from tests.test_sim import Gcs, of_type, parse

REAL_NAMES = {
    "apm25": [
        "RATE_RLL_P",
        "RATE_PIT_P",
        "RATE_YAW_P",
        "STB_RLL_P",
        "STB_PIT_P",
        "STB_YAW_P",
        "AHRS_RP_P",
        "AHRS_YAW_P",
        "COMPASS_DEC",
        "SR0_RAW_SENS",
        "INS_GYROFFS_X",
    ],
    "pixhawk": [
        "ATC_RAT_RLL_P",
        "ATC_ANG_RLL_P",
        "AHRS_RP_P",
        "AHRS_YAW_P",
        "COMPASS_DEC",
        "SR0_EXTRA1",
        "SERVO16_FUNCTION",
    ],
    "px4": ["MC_ROLLRATE_P", "MC_ROLL_P", "SYS_AUTOSTART", "ATT_W_ACC", "PWM_MAIN_MIN8"],
}


def download(sim: SimVehicle, mavlink1: bool, seconds: float = 5.0) -> list:
    """PARAM_REQUEST_LIST, then every PARAM_VALUE the vehicle streams within `seconds`."""
    Gcs(sim, mavlink1).send(mavlink.MAVLink_param_request_list_message(1, 1))
    return of_type(parse(sim.advance(sim.t + seconds)), "PARAM_VALUE")


@pytest.mark.parametrize("profile", ["apm25", "pixhawk", "px4"])
def test_param_list_streams_the_whole_table_paced(profile):
    sim = SimVehicle(profile=profile)
    assert len(sim.params) >= 500
    assert all(name in sim.params for name in REAL_NAMES[profile])
    values = download(sim, profile == "apm25", seconds=1.0)
    assert 240 <= len(values) <= 260  # 250 per second, like firmware pacing
    values += of_type(parse(sim.advance(sim.t + 5.0)), "PARAM_VALUE")
    assert sorted(v.param_index for v in values) == list(range(len(sim.params)))
    assert {v.param_count for v in values} == {len(sim.params)}
    assert {v.param_id for v in values} == set(sim.params.names)


def test_compass_dec_is_the_simulated_declination():
    faults = SensorFaults(declination=0.2)
    for profile in ("apm25", "pixhawk"):
        sim = SimVehicle(profile=profile, faults=faults)
        assert sim.params["COMPASS_DEC"] == pytest.approx(0.2)
        (value,) = of_type(
            Gcs(sim, profile == "apm25").send(mavlink.MAVLink_param_request_read_message(1, 1, b"COMPASS_DEC", -1)),
            "PARAM_VALUE",
        )
        assert value.param_value == pytest.approx(0.2)


def test_ardupilot_read_set_echo_with_float_encoding():
    sim = SimVehicle(profile="apm25")
    gcs = Gcs(sim, mavlink1=True)
    (by_name,) = of_type(
        gcs.send(mavlink.MAVLink_param_request_read_message(1, 1, b"SYSID_THISMAV", -1)), "PARAM_VALUE"
    )
    assert by_name.param_value == 1.0 and by_name.param_type == mavlink.MAV_PARAM_TYPE_INT16
    (by_index,) = of_type(
        gcs.send(mavlink.MAVLink_param_request_read_message(1, 1, b"", by_name.param_index)), "PARAM_VALUE"
    )
    assert by_index.param_id == "SYSID_THISMAV"
    (echo,) = of_type(
        gcs.send(mavlink.MAVLink_param_set_message(1, 1, b"RATE_RLL_P", 0.17, mavlink.MAV_PARAM_TYPE_REAL32)),
        "PARAM_VALUE",
    )
    assert echo.param_id == "RATE_RLL_P" and echo.param_value == pytest.approx(0.17)
    assert sim.params["RATE_RLL_P"] == pytest.approx(0.17)
    (rounded,) = of_type(
        gcs.send(mavlink.MAVLink_param_set_message(1, 1, b"LOG_BITMASK", 830.6, mavlink.MAV_PARAM_TYPE_INT16)),
        "PARAM_VALUE",
    )
    assert rounded.param_value == 831.0  # integers stored as integers, sent as plain floats
    assert gcs.send(mavlink.MAVLink_param_set_message(1, 1, b"NO_SUCH_PARAM", 1, 9)) == []


def test_ahrs_gain_parameters_reach_the_onboard_filter():
    sim = SimVehicle(profile="pixhawk")
    Gcs(sim).send(mavlink.MAVLink_param_set_message(1, 1, b"AHRS_RP_P", 0.4, mavlink.MAV_PARAM_TYPE_REAL32))
    assert sim.autopilot.secondary.kp == pytest.approx(0.4)  # the DCM behind AHRS2


def test_px4_int32_parameter_round_trips_bytewise():
    sim = SimVehicle(profile="px4")
    gcs = Gcs(sim)
    (value,) = of_type(gcs.send(mavlink.MAVLink_param_request_read_message(1, 1, b"SYS_AUTOSTART", -1)), "PARAM_VALUE")
    assert value.param_type == mavlink.MAV_PARAM_TYPE_INT32
    assert struct.unpack("<i", struct.pack("<f", value.param_value))[0] == 4001
    assert value.param_value != 4001.0  # not a C cast
    wire = struct.unpack("<f", struct.pack("<i", 4010))[0]
    (echo,) = of_type(
        gcs.send(mavlink.MAVLink_param_set_message(1, 1, b"SYS_AUTOSTART", wire, mavlink.MAV_PARAM_TYPE_INT32)),
        "PARAM_VALUE",
    )
    assert struct.unpack("<i", struct.pack("<f", echo.param_value))[0] == 4010
    assert sim.params["SYS_AUTOSTART"] == 4010
    negative = struct.unpack("<f", struct.pack("<i", -1))[0]  # a NaN bit pattern on the wire
    (echo,) = of_type(
        gcs.send(mavlink.MAVLink_param_set_message(1, 1, b"COM_FLTMODE1", negative, mavlink.MAV_PARAM_TYPE_INT32)),
        "PARAM_VALUE",
    )
    assert struct.unpack("<i", struct.pack("<f", echo.param_value))[0] == -1
    (real,) = of_type(
        gcs.send(mavlink.MAVLink_param_set_message(1, 1, b"MC_ROLLRATE_P", 0.12, mavlink.MAV_PARAM_TYPE_REAL32)),
        "PARAM_VALUE",
    )
    assert real.param_value == pytest.approx(0.12)  # REAL32 stays a float


def test_param_drop_loses_about_that_fraction():
    sim = SimVehicle(profile="pixhawk", param_drop=0.3, seed=5)
    received = download(sim, mavlink1=False)
    assert len(received) / len(sim.params) == pytest.approx(0.7, abs=0.05)
    assert sim.param_server.dropped == len(sim.params) - len(received)
    sim.param_drop = 0.0  # a run-time change
    assert len(download(sim, mavlink1=False)) == len(sim.params)


def test_param_clamp_stores_a_different_value_than_requested():
    sim = SimVehicle(profile="pixhawk", param_clamp={"ATC_RAT_RLL_P": 0.5})
    gcs = Gcs(sim)
    (echo,) = of_type(
        gcs.send(mavlink.MAVLink_param_set_message(1, 1, b"ATC_RAT_RLL_P", 0.8, mavlink.MAV_PARAM_TYPE_REAL32)),
        "PARAM_VALUE",
    )
    assert echo.param_value == pytest.approx(0.5)
    (echo,) = of_type(
        gcs.send(mavlink.MAVLink_param_set_message(1, 1, b"ATC_RAT_RLL_P", 0.2, mavlink.MAV_PARAM_TYPE_REAL32)),
        "PARAM_VALUE",
    )
    assert echo.param_value == pytest.approx(0.2)
    sim.param_clamp["ATC_RAT_PIT_P"] = 0.1  # settable at run time
    (echo,) = of_type(
        gcs.send(mavlink.MAVLink_param_set_message(1, 1, b"ATC_RAT_PIT_P", 0.3, mavlink.MAV_PARAM_TYPE_REAL32)),
        "PARAM_VALUE",
    )
    assert echo.param_value == pytest.approx(0.1)
