"""Every sensor of every log reaches the estimators: DataFlash in both time formats (TimeMS of
ArduCopter 3.1-3.2, TimeUS since) with IMU instances, MAG and GPS; the ULog magnetometer and GPS
topics; damaged and unreadable logs through `gcs estimate`."""

from __future__ import annotations

import csv
import dataclasses
import math

import numpy as np
import pytest
from conftest import LOGS
from pymavlink import mavutil
from pymavlink.DFReader import DFReader_binary
from pyulog import ULog
from ulog_writer import UlogWriter

from gcs.commands.cli import main
from gcs.core.estimation import GainChange, compare_stream
from gcs.core.estimators import registry
from gcs.core.samples import GpsSample, ImuSample
from gcs.logs.dataflash import DataflashLog
from gcs.logs.ulog import GPS_TOPICS, MAG_TOPICS, UlogFile
from gcs.sim.dataflash import DataflashWriter

HOP = LOGS / "arducopter-sitl-hop.BIN"
#: Magnetic declination at the SITL home (Canberra), as tests/test_dcm.py uses for this flight.
HOP_DECLINATION = math.radians(12.5)
ESTIMATORS = ("dcm", "ekf", "kf")


def estimate(log, name, out, *extra):
    """`gcs estimate` output rows as an array (t, qw, qx, qy, qz, roll, pitch, yaw)."""
    argv = ["estimate", str(log), "-e", name, "--gain", f"declination={HOP_DECLINATION}", "-o", str(out), *extra]
    assert main(argv) == 0
    with open(out) as fh:
        rows = list(csv.reader(fh))[1:]
    return np.array(rows, dtype=float)


def angle_deg(a, b):
    """Rotation angle between the attitudes of two output arrays, per row, degrees: from the
    chord |qa - qb| = 2 sin(angle / 4), which stays exact for tiny angles (an arccos does not)."""
    qa, qb = a[:, 1:5], b[:, 1:5]
    chord = np.minimum(np.linalg.norm(qa - qb, axis=1), np.linalg.norm(qa + qb, axis=1))
    return np.degrees(4 * np.arcsin(np.clip(chord / 2, 0.0, 1.0)))


@pytest.mark.parametrize("name", ESTIMATORS)
def test_timems_and_timeus_logs_give_the_same_estimates(hop_logs, tmp_path, name):
    folder, _ = hop_logs
    old = estimate(folder / "old.bin", name, tmp_path / "old.csv")
    new = estimate(folder / "new.bin", name, tmp_path / "new.csv")
    assert old.shape == new.shape == (2450, 8)  # one row per IMU record of instance 0
    np.testing.assert_allclose(old[:, 0], new[:, 0], atol=1e-9)
    assert angle_deg(old, new).max() < 1e-5  # measured ≤ 1e-6°: float32 GPS speed in the new layout
    # Against the original log (µs clock, float GPS): only the ms quantisation of time differs.
    original = estimate(HOP, name, tmp_path / "original.csv")
    assert np.abs(original[:, 0] - old[:, 0]).max() <= 0.5e-3 + 1e-9
    assert math.sqrt(np.mean(angle_deg(original, old) ** 2)) < 0.05  # measured 0.005-0.012°


def test_timems_gps_is_stamped_with_boot_time_not_gps_time_of_week(hop_logs):
    """ArduCopter 3.2's GPS record carries the receiver's time of week in TimeMS (here the SITL's
    own, about 4.5 days into the week) and the boot time in T: the GPS samples must fall where
    the TimeUS log has them, inside the IMU's time span, or GPS aiding never meets the IMU."""
    folder, _ = hop_logs
    old, new = (list(DataflashLog(str(folder / name))) for name in ("old.bin", "new.bin"))
    old_gps, new_gps = ([s.t for s in log if isinstance(s, GpsSample)] for log in (old, new))
    imu_t = [s.t for s in old if isinstance(s, ImuSample)]
    assert len(old_gps) == len(new_gps) > 100
    np.testing.assert_allclose(old_gps, new_gps, atol=1e-9)
    assert imu_t[0] <= old_gps[0] and old_gps[-1] <= imu_t[-1] + 1.0
    week_ms = [r.TimeMS for r in _records(folder / "old.bin", "GPS")]
    assert min(week_ms) > 1000 * (imu_t[-1] + 1.0)  # the records' TimeMS is not the boot time


def test_gps_without_boot_time_takes_the_time_of_the_record_before_it(tmp_path):
    """ArduCopter 3.1's GPS record has no boot time at all (TimeMS is GPS time of week): it is
    stamped with the record before it, the loop that logged it."""
    writer = DataflashWriter()
    writer.define("IMU", "Iffffff", "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ")
    writer.define("GPS", "BIHBcLLeeEe", "Status,TimeMS,Week,NSats,HDop,Lat,Lng,RelAlt,Alt,Spd,GCrs")
    for ms in range(0, 2000, 10):
        writer.add("IMU", ms, 0.0, 0.0, 0.0, 0.0, 0.0, -9.8)
        if ms % 200 == 100:
            writer.add("GPS", 3, 130_040_000 + ms, 1769, 10, 90, -353_632_610, 1_491_652_299, 0, 58_400, 200, 9_000)
    path = tmp_path / "ac31.bin"
    path.write_bytes(writer.bytes())
    gps = [s for s in DataflashLog(str(path)) if isinstance(s, GpsSample)]
    assert [round(s.t, 3) for s in gps] == [round(0.1 + 0.2 * k, 3) for k in range(10)]
    assert gps[0].vel_ned[1] == pytest.approx(2.0)  # 2 m/s east


def _records(path, kind):
    log = DFReader_binary(str(path))
    while (r := log.recv_match(type=kind)) is not None:
        yield r


def test_imu_option_selects_the_instance_in_both_formats(hop_logs, tmp_path, capsys):
    folder, _ = hop_logs
    log = DFReader_binary(str(HOP))
    second = []
    while (r := log.recv_match(type="IMU")) is not None:
        if r.I == 1:
            second.append((r.GyrX, r.GyrY, r.GyrZ))
    for path in (folder / "old.bin", folder / "new.bin"):
        gyro = [s.gyro.tolist() for s in DataflashLog(str(path), imu=1) if isinstance(s, ImuSample)]
        np.testing.assert_allclose(gyro, second, rtol=1e-6)
    old = estimate(folder / "old.bin", "dcm", tmp_path / "old.csv", "--imu", "1")
    new = estimate(folder / "new.bin", "dcm", tmp_path / "new.csv", "--imu", "1")
    first = estimate(folder / "old.bin", "dcm", tmp_path / "first.csv")
    assert angle_deg(old, new).max() < 1e-3 and angle_deg(old, first).max() > 0.01
    capsys.readouterr()
    # one line that says which instances the log has (it read "offset N: no IMU records of instance
    # 2 (instances in the log: 0, 1); is this a DataFlash log?", after the damage of a cut log: HOP)
    for path in (folder / "old.bin", HOP):
        assert main(["estimate", str(path), "-e", "dcm", "--imu", "2", "-o", str(tmp_path / "x.csv")]) == 2
        err = capsys.readouterr().err.splitlines()
        assert err == [f"gcs estimate: error: {path}: offset 0: no IMU instance 2; the log has IMU instances 0 and 1"]
        assert not (tmp_path / "x.csv").exists()


def test_truncated_old_log_is_estimated_up_to_the_damage(hop_logs, tmp_path, capsys):
    _, writer = hop_logs
    k = next(i for i, (name, end) in enumerate(writer.ends) if name == "IMU" and end > writer.size // 2)
    start, cut = writer.ends[k - 1][1], writer.ends[k][1] - 7  # cut inside record k
    path = tmp_path / "cut.bin"
    path.write_bytes(writer.bytes()[:cut])
    capsys.readouterr()
    rows = estimate(path, "dcm", tmp_path / "out.csv")
    err = capsys.readouterr().err.splitlines()
    # the offset is the cut record's: its header and part of its body are there
    length = writer.ends[k][1] - start
    cause = f"log ends inside a record ({cut - start} of its {length} bytes); records up to there are used"
    expected = f"gcs estimate: damage: {path}: offset {start}: {cause}"
    damage = [line for line in err if "damage" in line]
    assert damage == [expected], err
    assert [line for line in err if line not in damage and "declination" not in line] == []  # nothing else
    assert len(rows) == sum(1 for name, end in writer.ends[:k] if name == "IMU")


def test_unreadable_log_exits_2_with_one_line_and_no_output(tmp_path, capsys):
    bad = tmp_path / "junk.bin"
    bad.write_bytes(bytes(range(256)) * 8)
    out = tmp_path / "out.csv"
    assert main(["estimate", str(bad), "-e", "ekf", "-o", str(out)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and str(bad) in err[0] and "offset" in err[0]
    assert not out.exists()
    out.write_text("an earlier result\n")  # a failed run never clobbers an existing output
    assert main(["estimate", str(bad), "-e", "ekf", "-o", str(out)]) == 2
    assert out.read_text() == "an earlier result\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["junk.bin", "out.csv"]  # no temporary left


@pytest.mark.parametrize("name", ["arducopter-sitl-hop.BIN", "ardupilot-fragment.bin"])
def test_dataflash_mag_and_gps_reach_the_estimators(name):
    """The first MAG record (milligauss) rides on the IMU samples after it, in gauss; every GPS
    record of instance 0 becomes a GpsSample."""
    path = str(LOGS / name)
    log = DFReader_binary(path)
    first_mag, gps = None, 0
    while (r := log.recv_match(type=["MAG", "GPS"])) is not None:
        if getattr(r, "I", 0) == 0:
            if r.get_type() == "MAG" and first_mag is None:
                first_mag = (r.MagX / 1000, r.MagY / 1000, r.MagZ / 1000)
            gps += r.get_type() == "GPS"
    reader = DataflashLog(path)
    samples = list(reader)
    imu = [s for s in samples if isinstance(s, ImuSample)]
    with_mag = [s for s in imu if s.mag is not None]
    assert len(with_mag) >= 0.9 * len(imu)
    np.testing.assert_allclose(with_mag[0].mag, first_mag)
    assert sum(isinstance(s, GpsSample) for s in samples) == gps > 0
    assert reader.notes == []


def test_hop_heading_follows_onboard_only_with_the_magnetometer():
    """Yaw RMS against the onboard EKF (ATT) and SITL truth (SIM): with the MAG records every
    estimator holds the heading (measured 5.9/2.9/3.6° vs ATT, 3.3/0.4/1.1° vs SIM for
    dcm/ekf/kf); gyro-only it starts at an unknown heading and stays off by 13-120°. The
    declination is the test's throughout (the log's own is tested below)."""
    samples = [s for s in DataflashLog(str(HOP)) if not isinstance(s, GainChange)]
    gyro_only = [dataclasses.replace(s, mag=None) if isinstance(s, ImuSample) else s for s in samples]
    for name in ESTIMATORS:
        refs = compare_stream(samples, registry.create(name, None, declination=HOP_DECLINATION)).summary()
        onboard, truth = (refs["references"][r]["session"]["rms"][2] for r in ("onboard", "truth"))
        assert onboard < 7.0 and truth < 4.0, f"{name}: yaw RMS {onboard:.1f}° vs ATT, {truth:.1f}° vs SIM"
        blind = compare_stream(gyro_only, registry.create(name, None, declination=HOP_DECLINATION)).summary()
        assert blind["references"]["truth"]["session"]["rms"][2] > 10.0


def test_px4_sample_heading_from_the_magnetometer_inside_sensor_combined(capsys, tmp_path):
    """PX4 1.7 and older log no magnetometer topic: sensor_combined carries the calibrated field
    (magnetometer_ga). Every IMU sample carries it (0.48 gauss here), so the heading follows the
    onboard one; without it the yaw drifts with the gyro. No GPS, and the reader says so."""
    path = str(LOGS / "px4-flight-sample.ulg")
    topics = {d.name for d in ULog(path).data_list}
    assert "sensor_combined" in topics and not topics & {*MAG_TOPICS, *GPS_TOPICS}
    reader = UlogFile(path)
    samples = list(reader)
    imu = [s for s in samples if isinstance(s, ImuSample)]
    assert all(s.mag is not None for s in imu)
    assert 0.45 < float(np.mean([np.linalg.norm(s.mag) for s in imu])) < 0.52
    assert not any(isinstance(s, GpsSample) for s in samples)
    assert [n.split(": ", 1)[1] for n in reader.notes] == [
        "4 logging dropouts, 119 ms of data lost (the longest 62 ms at offset 2445300)",
        "no sensor_gps or vehicle_gps_position topic: no GPS aiding",
    ]
    gyro_only = [dataclasses.replace(s, mag=None) if isinstance(s, ImuSample) else s for s in samples]
    for name in ESTIMATORS:
        yaw = compare_stream(samples, registry.create(name)).summary()["references"]["onboard"]["session"]["rms"][2]
        blind = compare_stream(gyro_only, registry.create(name)).summary()["references"]["onboard"]["session"]["rms"][2]
        assert yaw < 1.0 < 10.0 < blind, f"{name}: yaw RMS vs onboard {yaw:.2f}°, {blind:.1f}° from the gyro alone"
    assert main(["estimate", path, "-e", "dcm", "-o", str(tmp_path / "out.csv")]) == 0
    assert "no vehicle_magnetometer or sensor_mag topic" not in capsys.readouterr().err


def test_a_ulog_without_any_magnetometer_says_the_heading_is_the_gyros(tmp_path):
    w = UlogWriter()
    w.topic("sensor_combined", "uint64_t timestamp;float[3] gyro_rad;float[3] accelerometer_m_s2")
    for k in range(100):
        w.add("sensor_combined", timestamp=1_000_000 + 5_000 * k, gyro_rad=(0.0, 0.0, 0.0),
              accelerometer_m_s2=(0.0, 0.0, -9.80665))  # fmt: skip
    path = tmp_path / "no-mag.ulg"
    path.write_bytes(w.bytes())
    reader = UlogFile(str(path))
    assert not any(isinstance(s, ImuSample) and s.mag is not None for s in reader)
    assert [n.split(": ", 1)[1] for n in reader.notes] == [
        "no vehicle_magnetometer or sensor_mag topic: heading from the gyro only",
        "no sensor_gps or vehicle_gps_position topic: no GPS aiding",
    ]


#: ULog fixture: level, heading 60°, flying north-east at 3 m/s; field 0.25 G north, 0.40 G down.
YAW = math.radians(60.0)
FIELD_BODY = (0.25 * math.cos(YAW), -0.25 * math.sin(YAW), 0.40)
VEL_NED = (3.0 * math.cos(math.radians(45)), 3.0 * math.sin(math.radians(45)), 0.0)
GPS_FIELDS = (
    "float vel_m_s;float vel_n_m_s;float vel_e_m_s;float vel_d_m_s;float cog_rad;uint8_t fix_type;bool vel_ned_valid"
)


#: NOAA's wmm-calculator at the fixture's GPS position (Canberra, 2026-11-24; see test_declination).
CANBERRA_WMM_DEG = 12.6943
#: EKF2_MAG_DECL (degrees) of the PX4 ≥ 1.14 fixture: initial, and changed at CHANGE_US.
MAG_DECL_DEG, MAG_DECL_CHANGED_DEG, CHANGE_US = 10.0, 20.0, 1_500_000


def _ulog(modern: bool) -> bytes:
    """PX4 ≥ 1.14 topics (vehicle_magnetometer, sensor_gps in degrees) with EKF2_MAG_DECL, or
    older ones (sensor_mag, vehicle_gps_position in degE7 and mm) without: the WMM then."""
    w = UlogWriter()
    if modern:
        w.param("EKF2_MAG_DECL", MAG_DECL_DEG)
    w.topic("sensor_combined", "uint64_t timestamp;float[3] gyro_rad;float[3] accelerometer_m_s2")
    mag, gps = ("vehicle_magnetometer", "sensor_gps") if modern else ("sensor_mag", "vehicle_gps_position")
    w.topic(
        mag, "uint64_t timestamp;float[3] magnetometer_ga" if modern else "uint64_t timestamp;float x;float y;float z"
    )
    position = (
        "double latitude_deg;double longitude_deg;double altitude_msl_m"
        if modern
        else "int32_t lat;int32_t lon;int32_t alt"
    )
    w.topic(gps, f"uint64_t timestamp;{position};{GPS_FIELDS}")
    for k in range(600):  # 3 s at 200 Hz; mag at 50 Hz, GPS at 5 Hz
        t = 1_000_000 + 5_000 * k
        if k % 4 == 0:
            field = {"magnetometer_ga": FIELD_BODY} if modern else dict(zip("xyz", FIELD_BODY, strict=True))
            w.add(mag, timestamp=t, **field)
        w.add("sensor_combined", timestamp=t, gyro_rad=(0.0, 0.0, 0.0), accelerometer_m_s2=(0.0, 0.0, -9.80665))
        if modern and t == CHANGE_US:
            w.param("EKF2_MAG_DECL", MAG_DECL_CHANGED_DEG)
        if k % 40 == 0:
            where = (
                {"latitude_deg": -35.3632610, "longitude_deg": 149.1652299, "altitude_msl_m": 584.09}
                if modern
                else {"lat": -353632610, "lon": 1491652299, "alt": 584090}
            )
            vn, ve, vd = VEL_NED
            w.add(gps, timestamp=t, **where, vel_m_s=3.0, vel_n_m_s=vn, vel_e_m_s=ve, vel_d_m_s=vd,
                  cog_rad=math.radians(45), fix_type=3, vel_ned_valid=True)  # fmt: skip
    return w.bytes()


@pytest.mark.parametrize("modern", [True, False], ids=["px4-1.14", "older"])
def test_ulog_magnetometer_and_gps_topics(tmp_path, modern):
    path = tmp_path / "flight.ulg"
    path.write_bytes(_ulog(modern))
    reader = UlogFile(str(path))
    samples = list(reader)
    imu = [s for s in samples if isinstance(s, ImuSample)]
    gps = [s for s in samples if isinstance(s, GpsSample)]
    assert len(imu) == 600 and len(gps) == 15 and reader.notes == []
    assert all(s.mag is not None for s in imu)  # a reading at the first IMU timestamp, ranked before it
    np.testing.assert_allclose(imu[-1].mag, FIELD_BODY, rtol=1e-6)  # gauss, as logged
    g = gps[0]
    assert (g.lat, g.lon, g.alt) == pytest.approx((-35.363261, 149.1652299, 584.09))
    assert g.t == 1.0 and g.fix_type == 3 and g.course == pytest.approx(math.radians(45))
    np.testing.assert_allclose(g.vel_ned, VEL_NED, rtol=1e-6)
    for name in ESTIMATORS:  # the magnetic heading from the magnetometer topic (0° without it)
        out = tmp_path / f"{name}.csv"
        assert main(["estimate", str(path), "-e", name, "-o", str(out), "--gain", "declination=0"]) == 0
        with open(out) as fh:
            yaw = float(list(csv.reader(fh))[-1][7])
        assert yaw == pytest.approx(60.0, abs=1.0), name


@pytest.mark.parametrize("modern", [True, False], ids=["EKF2_MAG_DECL", "no-parameter"])
def test_ulog_declination_from_parameters_else_wmm(tmp_path, capsys, modern):
    """EKF2_MAG_DECL (degrees) reaches the estimators as a declination in radians, the initial value
    at the start and a change where it was logged; without it the WMM at the first 3D fix. The yaw
    is the magnetic 60° turned by it, and `gcs estimate` names the source."""
    path = tmp_path / "flight.ulg"
    path.write_bytes(_ulog(modern))
    samples = list(UlogFile(str(path)))
    changes = [(k, s.value) for k, s in enumerate(samples) if isinstance(s, GainChange)]
    imu_t = [s.t if isinstance(s, ImuSample) else None for s in samples]
    if modern:
        logged = [math.radians(MAG_DECL_DEG), math.radians(MAG_DECL_CHANGED_DEG)]
        assert [v for _, v in changes] == pytest.approx(logged)
        assert changes[0][0] == 0  # before the first sample
        assert next(t for t in imu_t[changes[1][0] :] if t is not None) == CHANGE_US / 1e6  # at its time
        final, source = MAG_DECL_CHANGED_DEG, "vehicle EKF2_MAG_DECL"
    else:
        assert len(changes) == 1 and math.degrees(changes[0][1]) == pytest.approx(CANBERRA_WMM_DEG, abs=0.05)
        final, source = CANBERRA_WMM_DEG, "WMM at -35.3633,149.1652"
    out = tmp_path / "ekf.csv"
    assert main(["estimate", str(path), "-e", "ekf", "-o", str(out)]) == 0
    assert capsys.readouterr().err.strip().endswith(f"deg from {source}")
    with open(out) as fh:
        t, yaw = np.array([(float(r[0]), float(r[7])) for r in list(csv.reader(fh))[1:]]).T
    if modern:  # 70° until the change, then turning to 80° without a jump (78.2° 1.5 s later)
        before, after = yaw[t < CHANGE_US / 1e6][-1], yaw[t >= CHANGE_US / 1e6]
        assert before == pytest.approx(60.0 + MAG_DECL_DEG, abs=1.0)
        assert abs(after[0] - before) < 0.5 and 60.0 + final - 2.5 < after[-1] < 60.0 + final
    else:
        assert yaw[-1] == pytest.approx(60.0 + final, abs=1.0)


def test_dataflash_compass_dec_from_parm_records(tmp_path, capsys):
    """The fragment's PARM records hold COMPASS_DEC (radians): `gcs estimate` applies and names it."""
    path = str(LOGS / "ardupilot-fragment.bin")
    log = DFReader_binary(path)
    logged = None
    while (r := log.recv_match(type=["PARM"])) is not None:
        logged = r.Value if r.Name == "COMPASS_DEC" else logged
    assert logged and abs(logged) > 0.1
    changes = [s for s in DataflashLog(path) if isinstance(s, GainChange)]
    assert [c.value for c in changes] == pytest.approx([logged])
    assert main(["estimate", path, "-e", "dcm", "-o", str(tmp_path / "out.csv")]) == 0
    line = f"gcs estimate: declination {math.degrees(logged):.2f} deg from vehicle COMPASS_DEC"
    assert line in capsys.readouterr().err.splitlines()


def test_hop_bin_yaw_is_true_north_from_the_wmm():
    """The hop .BIN logs COMPASS_DEC = 0 (SITL writes its parameters before GPS lock: unset), so the
    WMM at the first 3D fix refers the yaw to true north: with their default (0) declination the
    estimators follow SIM to 0.9 / 1.2 / 2.1° yaw RMS (dcm / kf / ekf), 11.7-13.3° without it."""
    reader = DataflashLog(str(HOP))
    samples = list(reader)
    assert reader.declination.source == "WMM at -35.3633,149.1652"
    for name in ESTIMATORS:
        truth = compare_stream(samples, registry.create(name)).summary()["references"]["truth"]
        assert truth["session"]["rms"][2] < 3.0, name


def test_imu_option_on_a_tlog_and_a_csv(tmp_path, capsys):
    """A .tlog's second IMU is SCALED_IMU2 (ArduPilot sends its first as RAW_IMU); a CSV has one."""
    path = str(LOGS / "arducopter-sitl-hop.tlog")
    conn = mavutil.mavlink_connection(path)
    count = 0
    while (msg := conn.recv_match(type="SCALED_IMU2")) is not None:
        count += msg.get_srcSystem() == 1
    rows = estimate(path, "dcm", tmp_path / "out.csv", "--imu", "1")
    assert len(rows) == count > 1000
    (tmp_path / "in.csv").write_text("t,gx,gy,gz,ax,ay,az,mx,my,mz\n0,0,0,0,0,0,-9.8,,,\n")
    capsys.readouterr()
    assert main(["estimate", str(tmp_path / "in.csv"), "-e", "dcm", "--imu", "1", "-o", str(tmp_path / "c.csv")]) == 2
    assert "a CSV holds one IMU (instance 0), not instance 1" in capsys.readouterr().err
