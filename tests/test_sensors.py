"""Unit conversions and MAVLink → sample converters against hand-computed values."""

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from gcs.core import samples
from gcs.core.estimation import GainChange
from gcs.core.samples import AttitudeSample
from gcs.logs import dataflash, ulog
from gcs.mavlink import sampling
from gcs.sim.dataflash import NEW_FORMATS, OLD_FORMATS, DataflashWriter, e7, x100


def wire(msg, system=1):
    """The message as a receiver decodes it (real header, real source system)."""
    mav = mavlink.MAVLink(None, srcSystem=system, srcComponent=1)
    return mav.decode(bytearray(msg.pack(mav)))


def test_unit_conversions():
    assert samples.mg_to_mps2(1000) == pytest.approx(9.80665)
    assert samples.mg_to_mps2(-1001) == pytest.approx(-9.81645665, rel=1e-9)
    assert samples.mrad_to_rads(1500) == pytest.approx(1.5)
    assert samples.mgauss_to_gauss(224) == pytest.approx(0.224)
    assert samples.degE7_to_deg(-353632610) == pytest.approx(-35.363261)
    assert samples.cdeg_to_rad(18000) == pytest.approx(math.pi)
    assert samples.cm_to_m(250) == pytest.approx(2.5)
    assert samples.mm_to_m(584090) == pytest.approx(584.09)
    assert samples.hpa_to_pa(945.03) == pytest.approx(94503.0)
    assert samples.cdegc_to_degc(2606) == pytest.approx(26.06)
    assert samples.usec_to_s(14204316) == pytest.approx(14.204316)
    assert samples.ms_to_s(14204) == pytest.approx(14.204)


def test_raw_imu():
    msg = wire(mavlink.MAVLink_raw_imu_message(14204316, 10, -20, -1001, 100, -200, 300, 224, 80, -528, 0, 2524))
    s = sampling.sample_from_message(msg)
    assert isinstance(s, samples.ImuSample) and s.source == "RAW_IMU"
    assert s.t == pytest.approx(14.204316)
    np.testing.assert_allclose(s.accel, [0.0980665, -0.196133, -9.81645665], rtol=1e-6)
    np.testing.assert_allclose(s.gyro, [0.1, -0.2, 0.3])
    np.testing.assert_allclose(s.mag, [0.224, 0.080, -0.528])


def test_scaled_imu_without_compass():
    msg = wire(mavlink.MAVLink_scaled_imu2_message(5684, 0, 0, -1000, 0, 0, 0, 0, 0, 0, 2524))
    s = sampling.sample_from_message(msg)
    assert s.t == pytest.approx(5.684) and s.source == "SCALED_IMU2"
    assert s.mag is None
    assert s.accel[2] == pytest.approx(-9.80665)


def test_highres_imu_is_si():
    msg = wire(
        mavlink.MAVLink_highres_imu_message(
            2_000_000, 0.1, 0.2, -9.8, 0.01, 0.02, 0.03, 0.2, 0.0, 0.4, 1013.0, 0.0, 0.0, 20.0, 0, 0
        )
    )
    s = sampling.sample_from_message(msg)
    assert s.t == pytest.approx(2.0)
    np.testing.assert_allclose(s.accel, [0.1, 0.2, -9.8], rtol=1e-6)
    np.testing.assert_allclose(s.gyro, [0.01, 0.02, 0.03], rtol=1e-6)


def test_gps_raw_int():
    msg = wire(
        mavlink.MAVLink_gps_raw_int_message(55363000, 3, -353632610, 1491652299, 584090, 100, 100, 500, 9000, 10)
    )
    s = sampling.sample_from_message(msg)
    assert s.t == pytest.approx(55.363) and s.fix_type == 3
    assert (s.lat, s.lon, s.alt) == pytest.approx((-35.363261, 149.1652299, 584.09))
    assert s.ground_speed == pytest.approx(5.0) and s.course == pytest.approx(math.pi / 2)
    np.testing.assert_allclose(s.vel_ned, [0.0, 5.0, 0.0], atol=1e-12)


def test_gps_raw_int_unknown_velocity():
    msg = wire(mavlink.MAVLink_gps_raw_int_message(1, 3, 0, 0, 0, 100, 100, 65535, 65535, 10))
    s = sampling.sample_from_message(msg)
    assert math.isnan(s.ground_speed) and math.isnan(s.course) and s.vel_ned is None


def test_scaled_pressure_and_unknown_types():
    s = sampling.sample_from_message(wire(mavlink.MAVLink_scaled_pressure_message(5684, 945.03, 0.0, 2606)))
    assert (s.t, s.pressure, s.temperature) == pytest.approx((5.684, 94503.0, 26.06))
    assert sampling.sample_from_message(wire(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 0, 3))) is None


def test_vehicle_clock_stamps_untimed_messages_per_system():
    clock = sampling.VehicleClock()
    assert clock.observe(wire(mavlink.MAVLink_ahrs2_message(0.1, 0.2, 0.3, 0, 0, 0))) is None
    assert clock.observe(wire(mavlink.MAVLink_attitude_message(14204, 0, 0, 0, 0, 0, 0))) == pytest.approx(14.204)
    assert clock.observe(wire(mavlink.MAVLink_attitude_message(99000, 0, 0, 0, 0, 0, 0), system=2)) == 99.0
    assert clock.observe(wire(mavlink.MAVLink_simstate_message(0.1, 0.2, 0.3, 0, 0, 0, 0, 0, 0, 0, 0))) == 14.204


def _raw_imu(t_us):
    return wire(mavlink.MAVLink_raw_imu_message(t_us, 0, 0, -1000, 0, 0, 0, 200, 0, 400))


def test_ahrs2_takes_its_slot_time_and_simstate_the_previous():
    """ArduPilot sends a slot as AHRS2, ATTITUDE, RAW_IMU, SIMSTATE (ap_message order): AHRS2 gets
    the time of the ATTITUDE after it, SIMSTATE that of the messages before it, not the previous slot's."""
    sampler = sampling.MessageSampler()
    out = []
    for t_ms in (6000, 6040):  # after the boot's first 5 s: ATTITUDE is onboard
        out += sampler.feed(wire(mavlink.MAVLink_ahrs2_message(0.1, 0.2, 0.3, 0, 0, 0)))
        out += sampler.feed(wire(mavlink.MAVLink_attitude_message(t_ms, 0.11, 0.2, 0.3, 0, 0, 0)))
        out += sampler.feed(_raw_imu(t_ms * 1000 + 344))
        out += sampler.feed(wire(mavlink.MAVLink_simstate_message(0.12, 0.2, 0.3, 0, 0, 0, 0, 0, 0, 0, 0)))
    refs = [(s.source, s.t) for s in out if isinstance(s, AttitudeSample)]
    # the first AHRS2 came before any IMU message (the vehicle is not chosen yet) and is dropped;
    # the first ATTITUDE is passed on (a device that sends only its attitude is followed)
    assert refs == [
        ("onboard", 6.0),
        ("truth", pytest.approx(6.000344)),
        ("ahrs2", 6.04),
        ("onboard", 6.04),
        ("truth", pytest.approx(6.040344)),
    ]
    # without ATTITUDE in the stream, an AHRS2 followed by another keeps the previous time
    held = sampler.feed(wire(mavlink.MAVLink_ahrs2_message(0.1, 0.2, 0.3, 0, 0, 0)))
    assert held == []
    released = sampler.feed(wire(mavlink.MAVLink_ahrs2_message(0.1, 0.2, 0.3, 0, 0, 0)))
    assert [(s.source, s.t) for s in released] == [("ahrs2", pytest.approx(6.040344))]


def _ekf_status(flags: int):
    return wire(mavlink.MAVLink_ekf_status_report_message(flags, 0, 0, 0, 0, 0))


def test_attitude_is_onboard_only_while_the_vehicles_ekf_says_its_attitude_is_good():
    """ATTITUDE becomes UNREADY while the last EKF_STATUS_REPORT says the EKF is not initialised
    or its attitude not good (an ArduPlane's boot: a DCM swinging to 70° pitch), "onboard" once the
    EKF says so. Before a boot's first report it is UNREADY for the boot's first BOOT_SETTLE_S (5 s)
    of vehicle time, after a reboot too, and "onboard" from then on (a vehicle that sends no
    report). AHRS2 and SIMSTATE are not renamed."""
    inputs = sampling.MessageInputs()
    sources = []
    for t_ms, flags in ((1000, None), (2000, mavlink.EKF_UNINITIALIZED), (3000, 0),
                        (4000, mavlink.EKF_ATTITUDE | mavlink.EKF_VELOCITY_HORIZ), (5000, 0), (500, None),
                        (4900, None), (5000, None)):  # fmt: skip
        if flags is not None:
            assert inputs.feed(_ekf_status(flags)) == []
        out = inputs.feed(_raw_imu(t_ms * 1000))
        out += inputs.feed(wire(mavlink.MAVLink_attitude_message(t_ms, 0.1, 1.2, 0.3, 0, 0, 0)))
        out += inputs.feed(wire(mavlink.MAVLink_simstate_message(0.12, 0.2, 0.3, 0, 0, 0, 0, 0, 0, 0, 0)))
        sources.append([s.source for s in out if isinstance(s, AttitudeSample)])
    unready, onboard = [sampling.UNREADY, "truth"], ["onboard", "truth"]
    assert sources == [unready, unready, unready, onboard, unready, unready, unready, onboard]


def dataflash_samples(tmp_path, formats, records, imu=0):
    """The samples DataflashLog reads from a .bin of these record layouts and records (without
    the declination changes: a 3D fix gives one)."""
    writer = DataflashWriter()
    for name in dict.fromkeys(name for name, _ in records):
        writer.define(name, *formats[name])
    for name, values in records:
        writer.add(name, *values)
    path = tmp_path / "records.bin"
    path.write_bytes(writer.bytes())
    return [s for s in dataflash.DataflashLog(str(path), imu) if not isinstance(s, GainChange)]


def test_log_records(tmp_path):
    imu, gps = dataflash_samples(
        tmp_path,
        NEW_FORMATS,
        [
            ("IMU", (1_500_000, 0, 0.1, 0.2, 0.3, 0.0, 0.0, -9.8)),
            ("GPS", (2_000_000, 0, 3, 0, 0, 12, 90, e7(-35.0), e7(149.0), x100(584.0), 2.0, 180.0, -0.5, 0.0)),
        ],
    )
    assert imu.t == 1.5 and imu.gyro.tolist() == np.float32([0.1, 0.2, 0.3]).tolist() and imu.mag is None
    assert (gps.t, gps.lat, gps.lon, gps.alt, gps.fix_type) == (2.0, -35.0, 149.0, 584.0, 3)
    np.testing.assert_allclose(gps.vel_ned, [-2.0, 0.0, -0.5], atol=1e-12)
    combined = {"timestamp": np.array([3_000_000], dtype=np.uint64)}
    for i, (gyro, accel) in enumerate(zip([0.0, 0.1, 0.0], [0.0, 0.0, -9.81], strict=True)):
        combined[f"gyro_rad[{i}]"], combined[f"accelerometer_m_s2[{i}]"] = np.float32([gyro]), np.float32([accel])
    u = ulog.imu_rows(combined)
    assert u.shape == (1, 7) and u[0, 0] == 3.0
    np.testing.assert_array_equal(u[0, 1:], np.float32([0.0, 0.1, 0.0, 0.0, 0.0, -9.81]))


def test_old_dataflash_records_timems_and_instance_by_type(tmp_path):
    """ArduCopter 3.2: TimeMS in ms, the second IMU is its own type IMU2 (carrying the first
    compass, MAG, as the autopilot uses it), MAG in milligauss, GPS
    TimeMS the GPS time of week and T the boot time (ms), angles in centidegrees; 3.1's GPS
    (no T) takes the time of the record before it, 3.1's ATT (no time at all) is not used."""
    assert samples.ms_to_usec(1234) == 1_234_000
    gps = (3, 130_040_903, 1769, 12, 90, e7(-35.0), e7(149.0), 0, x100(584.0), x100(2.0), x100(90.0), 0.5)
    formats = {**OLD_FORMATS, "GPS1": ("BIHBcLLeeEef", "Status,TimeMS,Week,NSats,HDop,Lat,Lng,RelAlt,Alt,Spd,GCrs,VZ")}
    formats["ATT1"] = ("ccccCC", "DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw")
    records = [
        ("MAG", (1_000, 224, 80, -528, 0, 0, 0, 0, 0, 0)),
        ("IMU2", (1_500, 0.1, 0.2, 0.3, 0.0, 0.0, -9.8)),
        ("GPS", (*gps, 2_000)),
        ("ATT", (2_500, 0, -718, 0, 258, 0, 33710)),
        ("MAG", (2_600, 0, 0, 0, 0, 0, 0, 0, 0, 0)),
        ("IMU2", (2_700, 0.1, 0.2, 0.3, 0.0, 0.0, -9.8)),
    ]
    imu, g, att, no_mag = dataflash_samples(tmp_path, formats, records, imu=1)
    assert imu.t == 1.5 and imu.source == "IMU[1]"
    np.testing.assert_allclose(imu.mag, [0.224, 0.080, -0.528])
    assert no_mag.mag is None  # an all-zero field: no compass
    assert g.t == 2.0 and g.fix_type == 3 and g.course == pytest.approx(math.pi / 2)
    np.testing.assert_allclose(g.vel_ned, [0.0, 2.0, 0.5], atol=1e-12)
    assert att.t == 2.5 and att.roll == pytest.approx(math.radians(-7.18))
    assert att.yaw == pytest.approx(math.radians(337.1 - 360))
    # ArduCopter 3.1 (the record layouts renamed only so one file can hold both)
    formats = {"IMU": OLD_FORMATS["IMU"], "GPS": formats["GPS1"], "ATT": formats["ATT1"]}
    records = [("IMU", (1_500, 0.1, 0.2, 0.3, 0.0, 0.0, -9.8)), ("GPS", gps), ("ATT", (0, -718, 0, 258, 0, 33710))]
    imu, g = dataflash_samples(tmp_path, formats, records)
    assert g.t == 1.5 and g.lat == -35.0


@pytest.mark.parametrize("modern", [True, False])
def test_ulog_gps_rows_both_generations(modern):
    """sensor_gps since PX4 1.14 has latitude_deg/altitude_msl_m; before, lat/lon degE7 and alt mm."""
    position = (
        {"latitude_deg": np.array([-35.3632610]), "longitude_deg": np.array([149.1652299]), "altitude_msl_m": [584.09]}
        if modern
        else {"lat": np.array([-353632610]), "lon": np.array([1491652299]), "alt": np.array([584090])}
    )
    data = {
        "timestamp": np.array([5_000_000]),
        **position,
        "vel_m_s": np.array([2.0]),
        "vel_n_m_s": np.array([0.0]),
        "vel_e_m_s": np.array([-2.0]),
        "vel_d_m_s": np.array([0.1]),
        "cog_rad": np.array([-math.pi / 2]),
        "vel_ned_valid": np.array([1]),
        "fix_type": np.array([3]),
    }
    t, lat, lon, alt, speed, course, vn, ve, vd, fix = ulog.gps_rows(data)[0]
    assert t == 5.0 and (lat, lon, alt) == pytest.approx((-35.363261, 149.1652299, 584.09))
    assert speed == 2.0 and course == pytest.approx(-math.pi / 2) and fix == 3
    np.testing.assert_allclose([vn, ve, vd], [0.0, -2.0, 0.1])
    data["vel_ned_valid"] = np.array([0])
    assert np.isnan(ulog.gps_rows(data)[0, 6:9]).all()  # no NED velocity
