"""Unit conversions and MAVLink → sample converters against hand-computed values."""

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from gcs.core import samples
from gcs.core.samples import AttitudeSample
from gcs.logs import dataflash, ulog
from gcs.mavlink import sampling


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
    for t_ms in (1000, 1040):
        out += sampler.feed(wire(mavlink.MAVLink_ahrs2_message(0.1, 0.2, 0.3, 0, 0, 0)))
        out += sampler.feed(wire(mavlink.MAVLink_attitude_message(t_ms, 0.11, 0.2, 0.3, 0, 0, 0)))
        out += sampler.feed(_raw_imu(t_ms * 1000 + 344))
        out += sampler.feed(wire(mavlink.MAVLink_simstate_message(0.12, 0.2, 0.3, 0, 0, 0, 0, 0, 0, 0, 0)))
    refs = [(s.source, s.t) for s in out if isinstance(s, AttitudeSample)]
    # the first AHRS2 came before any IMU message (the vehicle is not chosen yet) and is dropped;
    # the first ATTITUDE is passed on (a device that sends only its attitude is followed)
    assert refs == [
        ("onboard", 1.0),
        ("truth", pytest.approx(1.000344)),
        ("ahrs2", 1.04),
        ("onboard", 1.04),
        ("truth", pytest.approx(1.040344)),
    ]
    # without ATTITUDE in the stream, an AHRS2 followed by another keeps the previous time
    held = sampler.feed(wire(mavlink.MAVLink_ahrs2_message(0.1, 0.2, 0.3, 0, 0, 0)))
    assert held == []
    released = sampler.feed(wire(mavlink.MAVLink_ahrs2_message(0.1, 0.2, 0.3, 0, 0, 0)))
    assert [(s.source, s.t) for s in released] == [("ahrs2", pytest.approx(1.040344))]


class Record:  # DataFlash rows are plain attribute bags with a type name; this is one, not a mock of one
    def __init__(self, kind, **kw):
        self.kind = kind
        self.__dict__.update(kw)

    def get_type(self):
        return self.kind


def test_log_records():
    s = dataflash.imu_from_dataflash(
        Record("IMU", TimeUS=1_500_000, I=0, GyrX=0.1, GyrY=0.2, GyrZ=0.3, AccX=0.0, AccY=0.0, AccZ=-9.8)
    )
    assert s.t == 1.5 and s.gyro.tolist() == [0.1, 0.2, 0.3] and s.mag is None
    g = dataflash.gps_from_dataflash(
        Record("GPS", TimeUS=2_000_000, I=0, Lat=-35.0, Lng=149.0, Alt=584.0, Spd=2.0, GCrs=180.0, VZ=-0.5, Status=3)
    )
    np.testing.assert_allclose(g.vel_ned, [-2.0, 0.0, -0.5], atol=1e-12)
    combined = {"timestamp": np.array([3_000_000], dtype=np.uint64)}
    for i, (gyro, accel) in enumerate(zip([0.0, 0.1, 0.0], [0.0, 0.0, -9.81], strict=True)):
        combined[f"gyro_rad[{i}]"], combined[f"accelerometer_m_s2[{i}]"] = np.float32([gyro]), np.float32([accel])
    u = ulog.imu_rows(combined)
    assert u.shape == (1, 7) and u[0, 0] == 3.0
    np.testing.assert_array_equal(u[0, 1:], np.float32([0.0, 0.1, 0.0, 0.0, 0.0, -9.81]))


def test_old_dataflash_records_timems_and_instance_by_type():
    """ArduCopter 3.2: TimeMS in ms, the second IMU is its own type IMU2, MAG in milligauss."""
    assert samples.ms_to_usec(1234) == 1_234_000
    mag = dataflash.mag_from_dataflash(Record("MAG2", TimeMS=1_000, MagX=224, MagY=80, MagZ=-528))
    assert mag.t == 1.0 and mag.source == "MAG[1]"
    np.testing.assert_allclose(mag.field, [0.224, 0.080, -0.528])
    assert dataflash.mag_from_dataflash(Record("MAG", TimeMS=1_000, MagX=0, MagY=0, MagZ=0)) is None
    s = dataflash.imu_from_dataflash(
        Record("IMU2", TimeMS=1_500, GyrX=0.1, GyrY=0.2, GyrZ=0.3, AccX=0.0, AccY=0.0, AccZ=-9.8), mag
    )
    assert s.t == 1.5 and s.source == "IMU[1]" and s.mag is mag.field
    fix = {"Lat": -35.0, "Lng": 149.0, "Alt": 584.0, "Spd": 2.0, "GCrs": 90.0, "VZ": 0.5, "Status": 3}
    # 3.2's GPS: TimeMS is the GPS time of week, T the boot time (ms)
    g = dataflash.gps_from_dataflash(Record("GPS", TimeMS=130_040_903, Week=1769, T=2_000, **fix))
    assert g.t == 2.0 and g.fix_type == 3 and g.course == pytest.approx(math.pi / 2)
    np.testing.assert_allclose(g.vel_ned, [0.0, 2.0, 0.5], atol=1e-12)
    att = dataflash.attitude_from_dataflash(Record("ATT", TimeMS=2_500, Roll=-7.18, Pitch=2.58, Yaw=337.1), "onboard")
    assert att.t == 2.5 and att.yaw == pytest.approx(math.radians(337.1 - 360))
    assert dataflash.record_time_us(Record("ATT", Roll=0.0)) is None  # ArduCopter 3.1's ATT has no time
    assert dataflash.record_time_us(Record("GPS", TimeMS=130_040_903, Week=1769, **fix)) is None  # 3.1's GPS


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
