"""The simulated vehicle through its deterministic API (`advance`) and pymavlink's own parser."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from gcs.mavlink.dialect import MARKER_V1, MARKER_V2, Encoder, mavlink
from gcs.sim import SensorFaults, SimVehicle
from gcs.sim.autopilot import milli_g
from gcs.sim.motion import GRAVITY

GCS_SYSID, GCS_COMPID = 255, 190


def parse(packets: list[bytes]) -> list:
    parser = mavlink.MAVLink(None)
    return [m for packet in packets for m in parser.parse_buffer(packet) or []]


def of_type(messages, kind: str) -> list:
    return [m for m in messages if m.get_type() == kind]


class Gcs:
    """Ground-station side: encodes requests into the vehicle's handle_bytes."""

    def __init__(self, sim: SimVehicle, mavlink1: bool = False) -> None:
        self.sim = sim
        self.encoder = Encoder(GCS_SYSID, GCS_COMPID, mavlink1=mavlink1)

    def send(self, msg) -> list:
        """Send one message; return the vehicle's immediate replies, parsed."""
        self.sim.handle_bytes(self.encoder.encode(msg))
        return parse(self.sim.take_replies())

    def request_stream(self, stream_id: int, hz: int, start: int = 1) -> list:
        return self.send(mavlink.MAVLink_request_data_stream_message(1, 1, stream_id, hz, start))

    def command(self, command: int, *params: float) -> list:
        p = list(params) + [0.0] * (7 - len(params))
        return self.send(mavlink.MAVLink_command_long_message(1, 1, command, 0, *p))

    def set_interval(self, name: str, interval_us: float) -> list:
        msg_id = getattr(mavlink, f"MAVLINK_MSG_ID_{name}")
        return self.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, interval_us)


def attitude_simstate_pairs(messages) -> list:
    """(ATTITUDE, SIMSTATE) sent at the same instant: SIMSTATE has no timestamp, but the vehicle
    sends messages due together in a fixed order, ATTITUDE first."""
    pairs, attitude = [], None
    for m in messages:
        if m.get_type() == "ATTITUDE":
            attitude = m
        elif m.get_type() == "SIMSTATE" and attitude is not None:
            pairs.append((attitude, m))
            attitude = None
    return pairs


def ack_result(replies) -> int:
    (ack,) = of_type(replies, "COMMAND_ACK")
    return ack.result


# --- apm25 ---------------------------------------------------------------------------------------


def test_apm25_sends_only_heartbeat_until_requested_then_raw_imu_at_rate_in_mavlink1():
    sim = SimVehicle(profile="apm25", script="bench", seed=1)
    before = sim.advance(10.0)
    assert {m.get_type() for m in parse(before)} == {"HEARTBEAT"}
    assert 10 <= len(before) <= 11
    hb = parse(before)[0]
    assert hb.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA and hb.type == mavlink.MAV_TYPE_QUADROTOR

    Gcs(sim, mavlink1=True).request_stream(mavlink.MAV_DATA_STREAM_RAW_SENSORS, 25)
    after = sim.advance(30.0)
    assert all(p[0] == MARKER_V1 for p in before + after)
    raw = of_type(parse(after), "RAW_IMU")
    assert len(raw) == pytest.approx(25 * 20, rel=0.02)
    times = np.array([m.time_usec for m in raw]) * 1e-6
    assert 1 / np.mean(np.diff(times)) == pytest.approx(25, rel=0.01)
    kinds = {m.get_type() for m in parse(after)}
    assert {"SCALED_PRESSURE", "SENSOR_OFFSETS"} <= kinds and "ATTITUDE" not in kinds


def test_apm25_raw_imu_units_level_and_still():
    sim = SimVehicle(profile="apm25", script="bench", faults=SensorFaults.perfect())
    Gcs(sim, mavlink1=True).request_stream(mavlink.MAV_DATA_STREAM_RAW_SENSORS, 50)
    raw = of_type(parse(sim.advance(1.5)), "RAW_IMU")  # the bench script starts with 2 s level
    assert raw
    for m in raw:
        assert (m.xacc, m.yacc, m.zacc) == (0, 0, -1000)  # mG
        assert (m.xgyro, m.ygyro, m.zgyro) == (0, 0, 0)  # mrad/s
        field = sim.faults.earth_field()  # level, heading north: body = NED, mgauss
        assert (m.xmag, m.ymag, m.zmag) == tuple(round(1000 * b) for b in field)

    noisy = SimVehicle(profile="apm25", script="bench", seed=3)
    Gcs(noisy, mavlink1=True).request_stream(mavlink.MAV_DATA_STREAM_RAW_SENSORS, 50)
    raw = of_type(parse(noisy.advance(1.5)), "RAW_IMU")
    assert np.mean([m.zacc for m in raw]) == pytest.approx(-1000, abs=15)
    assert max(abs(m.xgyro) for m in raw) < 25


def test_ardupilot_accel_unit_is_milli_g_of_gravity_mss():
    assert milli_g(2 * GRAVITY) == 2000 and milli_g(-GRAVITY / 2) == -500
    assert milli_g(1000 * GRAVITY) == 32767  # int16 saturates, never wraps


def test_apm25_group_stop_cap_all_and_unknown_commands():
    sim = SimVehicle(profile="apm25", script="quad")
    gcs = Gcs(sim, mavlink1=True)
    gcs.request_stream(mavlink.MAV_DATA_STREAM_ALL, 200)
    rates = sim.stream_rates()
    assert rates["RAW_IMU"] == 50 and rates["ATTITUDE"] == 50 and rates["AHRS"] == 50
    assert rates["SENSOR_OFFSETS"] == pytest.approx(50 / 11)
    assert rates["GPS_RAW_INT"] == 5  # one per fix
    assert "AHRS2" not in rates and "SCALED_IMU2" not in rates
    gcs.request_stream(mavlink.MAV_DATA_STREAM_EXTRA1, 10, start=0)
    assert "ATTITUDE" not in sim.stream_rates() and "SIMSTATE" not in sim.stream_rates()
    sim.advance(5.0)
    kinds = {m.get_type() for m in parse(sim.advance(10.0))}
    assert "ATTITUDE" not in kinds and "AHRS2" not in kinds and "RAW_IMU" in kinds

    replies = gcs.set_interval("ATTITUDE", 20000)
    assert ack_result(replies) == mavlink.MAV_RESULT_UNSUPPORTED
    assert ack_result(gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, 148)) == mavlink.MAV_RESULT_UNSUPPORTED
    assert "ATTITUDE" not in sim.stream_rates()


def test_apm25_ignores_mavlink2_frames():
    sim = SimVehicle(profile="apm25")
    Gcs(sim, mavlink1=False).request_stream(mavlink.MAV_DATA_STREAM_ALL, 10)
    assert set(sim.stream_rates()) == {"HEARTBEAT"}


def test_arm_disarm_shows_in_heartbeat():
    sim = SimVehicle(profile="apm25")
    gcs = Gcs(sim, mavlink1=True)
    assert ack_result(gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)) == mavlink.MAV_RESULT_ACCEPTED
    hb = of_type(parse(sim.advance(1.5)), "HEARTBEAT")[-1]
    assert hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0)
    hb = of_type(parse(sim.advance(3.0)), "HEARTBEAT")[-1]
    assert not hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED


# --- pixhawk -------------------------------------------------------------------------------------


def test_pixhawk_set_message_interval_acked_and_honoured_without_drift():
    sim = SimVehicle(profile="pixhawk", script="circuit")
    gcs = Gcs(sim)
    assert set(sim.stream_rates()) == {"HEARTBEAT"}  # Copter SRx default 0
    assert ack_result(gcs.set_interval("ATTITUDE", 20000)) == mavlink.MAV_RESULT_ACCEPTED
    packets = sim.advance(20.0)
    assert all(p[0] == MARKER_V2 for p in packets)
    att = of_type(parse(packets), "ATTITUDE")
    assert len(att) == pytest.approx(50 * 20, rel=0.01)
    assert np.ptp(np.diff([m.time_boot_ms for m in att])) <= 1  # ms rounding only

    assert ack_result(gcs.set_interval("RAW_IMU", 100)) == mavlink.MAV_RESULT_ACCEPTED  # 10 kHz asked
    assert sim.stream_rates()["RAW_IMU"] == 320  # 0.8 × 400 Hz loop
    gcs.set_interval("ATTITUDE", -1)
    assert "ATTITUDE" not in sim.stream_rates()
    gcs.request_stream(mavlink.MAV_DATA_STREAM_EXTRA1, 4)
    gcs.set_interval("ATTITUDE", 0)  # back to the group's rate
    assert sim.stream_rates()["ATTITUDE"] == 4 and sim.stream_rates()["AHRS2"] == 4
    assert ack_result(gcs.set_interval("HIGHRES_IMU", 1000)) == mavlink.MAV_RESULT_FAILED
    replies = gcs.command(mavlink.MAV_CMD_GET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_RAW_IMU)
    assert ack_result(replies) == mavlink.MAV_RESULT_ACCEPTED
    assert of_type(replies, "MESSAGE_INTERVAL")[0].interval_us == 3125  # 320 Hz


def test_ground_station_heartbeats_are_accepted_silently_and_other_systems_ignored():
    sim = SimVehicle(profile="pixhawk")
    gcs = Gcs(sim)
    heartbeat = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)
    assert gcs.send(heartbeat) == []
    assert sim.received["HEARTBEAT"] == 1
    other = mavlink.MAVLink_command_long_message(7, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    assert gcs.send(other) == [] and not sim.armed  # addressed to system 7
    assert gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, float("nan"), 1000) == [] and sim.rejected == 1
    sim.handle_bytes(b"\xfd\x09garbage" * 10)  # line noise, with false start-of-frame markers
    replies = [r for _ in range(3) for r in gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)]
    assert of_type(replies, "COMMAND_ACK") and sim.armed  # the parser resynchronises


def test_pixhawk_autopilot_version_and_second_imu():
    sim = SimVehicle(profile="pixhawk")
    gcs = Gcs(sim)
    replies = gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    assert ack_result(replies) == mavlink.MAV_RESULT_ACCEPTED
    (version,) = of_type(replies, "AUTOPILOT_VERSION")
    assert version.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    assert version.flight_sw_version >> 24 == 4
    gcs.request_stream(mavlink.MAV_DATA_STREAM_RAW_SENSORS, 20)
    msgs = parse(sim.advance(2.0))
    imu1, imu2 = of_type(msgs, "RAW_IMU"), of_type(msgs, "SCALED_IMU2")
    assert len(imu2) == len(imu1) > 30
    assert [m.zacc for m in imu1] != [m.zacc for m in imu2]  # independent noise
    assert np.mean([m.zacc for m in imu2]) == pytest.approx(-1000, abs=15)


# --- px4 -----------------------------------------------------------------------------------------


def test_px4_ignores_request_data_stream_and_sends_highres_imu_in_si():
    sim = SimVehicle(profile="px4", script="bench")
    gcs = Gcs(sim)
    assert gcs.request_stream(mavlink.MAV_DATA_STREAM_ALL, 50) == []
    msgs = parse(sim.advance(4.0))
    assert not of_type(msgs, "HIGHRES_IMU")
    assert len(of_type(msgs, "ATTITUDE")) == pytest.approx(15 * 4, abs=1)
    assert of_type(msgs, "HEARTBEAT")[0].autopilot == mavlink.MAV_AUTOPILOT_PX4

    assert ack_result(gcs.set_interval("HIGHRES_IMU", 2500)) == mavlink.MAV_RESULT_ACCEPTED
    imu = of_type(parse(sim.advance(6.0)), "HIGHRES_IMU")
    assert len(imu) == pytest.approx(400 * 2, abs=1)
    level = SimVehicle(profile="px4", script="bench", faults=SensorFaults.perfect())
    Gcs(level).set_interval("HIGHRES_IMU", 10000)
    m = of_type(parse(level.advance(1.0)), "HIGHRES_IMU")[-1]  # bench: level and still until 2 s
    assert m.zacc == pytest.approx(-GRAVITY, abs=1e-4) and abs(m.xacc) < 1e-6
    assert math.hypot(m.xmag, m.ymag, m.zmag) == pytest.approx(level.faults.field_strength, rel=1e-5)  # gauss
    assert m.abs_pressure == pytest.approx(745.0, abs=5)  # hPa at 2556 m
    assert m.fields_updated == 0x1FFF
    Gcs(level).set_interval("ATTITUDE_QUATERNION", 20000)
    quats = of_type(parse(level.advance(1.9)), "ATTITUDE_QUATERNION")
    assert len(quats) == pytest.approx(45, abs=1)
    assert math.hypot(quats[-1].q1, quats[-1].q2, quats[-1].q3, quats[-1].q4) == pytest.approx(1.0, abs=1e-6)


def test_px4_autopilot_version_says_bytewise_params():
    replies = Gcs(SimVehicle(profile="px4")).command(mavlink.MAV_CMD_REQUEST_MESSAGE, 148)
    (version,) = of_type(replies, "AUTOPILOT_VERSION")
    assert version.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    assert version.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2


# --- truth ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("profile", ["apm25", "pixhawk", "px4"])
def test_simstate_is_the_truth_and_attitude_is_an_estimate(profile):
    sim = SimVehicle(profile=profile, script="quad", seed=2)
    gcs = Gcs(sim, mavlink1=profile == "apm25")
    if profile == "px4":
        gcs.set_interval("SIMSTATE", 100000)
        gcs.set_interval("ATTITUDE", 100000)
    else:
        gcs.request_stream(mavlink.MAV_DATA_STREAM_EXTRA1, 10)
    pairs = attitude_simstate_pairs(parse(sim.advance(40.0)))
    assert len(pairs) > 350
    worst = 0.0
    for att, state in pairs:
        truth = sim.truth(att.time_boot_ms / 1000)
        assert (state.roll, state.pitch, state.yaw) == pytest.approx(truth.euler, abs=1e-6)
        assert (state.xgyro, state.ygyro, state.zgyro) == pytest.approx(truth.omega_body, abs=1e-6)
        assert (state.xacc, state.yacc, state.zacc) == pytest.approx(truth.specific_force, abs=1e-5)
        lat, lon = sim.home.lat_lon(truth.pos[0], truth.pos[1])
        assert (state.lat, state.lng) == (round(lat * 1e7), round(lon * 1e7))
        worst = max(worst, abs(att.roll - state.roll), abs(att.pitch - state.pitch))
    assert 0.001 < worst < math.radians(10)  # an estimate: close, never identical


def test_onboard_attitude_tracks_the_bench_script_within_a_few_degrees():
    sim = SimVehicle(profile="apm25", script="bench", seed=4)
    Gcs(sim, mavlink1=True).request_stream(mavlink.MAV_DATA_STREAM_EXTRA1, 10)
    pairs = attitude_simstate_pairs(parse(sim.advance(sim.script.period)))
    errors = [max(abs(a.roll - s.roll), abs(a.pitch - s.pitch)) for a, s in pairs]
    assert np.mean(errors) < math.radians(1.0) and max(errors) < math.radians(4.0)


def test_determinism_same_seed_same_bytes():
    def run(seed: int) -> bytes:
        sim = SimVehicle(profile="pixhawk", script="circuit", seed=seed)
        gcs = Gcs(sim)
        gcs.request_stream(mavlink.MAV_DATA_STREAM_ALL, 20)
        out = sim.advance(3.0)
        gcs.set_interval("RAW_IMU", 5000)
        gcs.send(mavlink.MAVLink_param_request_list_message(1, 1))
        out += sim.take_replies() + sim.advance(6.0)
        return b"".join(out)

    assert run(7) == run(7)
    assert run(7) != run(8)


def test_advance_cost_at_400_hz_imu():
    """60 s of vehicle time with 400 Hz IMU + 50 Hz ATTITUDE + 5 Hz GPS: far faster than real time."""
    sim = SimVehicle(profile="px4", script="quad")
    gcs = Gcs(sim)
    gcs.set_interval("HIGHRES_IMU", 2500)
    gcs.set_interval("ATTITUDE", 20000)
    gcs.set_interval("GPS_RAW_INT", 200000)
    start = time.perf_counter()
    packets = sim.advance(60.0)
    wall = time.perf_counter() - start
    print(f"advance(60 s) at 400 Hz IMU: {wall:.2f} s wall, {len(packets)} packets")
    assert len(packets) > 60 * 455
    assert wall < 20.0
