"""The ULog column reader (gcs.logs.ulog_format + gcs.logs.ulog) gives exactly the samples pyulog
gives (tests/pyulog_reference.py: pyulog decoding, per-topic objects, heapq merge), field by field
and bit for bit, on every shared .ulg and on written logs with a magnetometer, GPS, parameter
changes and a topic out of time order; a cut or damaged file is read up to the damage with one
line naming the offset and the cause; `gcs replay --fast` estimates exactly as from pyulog's samples."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
import pyulog_reference
from conftest import LOGS
from pyulog_reference import assert_same_samples
from ulog_writer import UlogWriter

from gcs.commands.cli import main
from gcs.core.estimation import GainChange
from gcs.core.estimators import registry
from gcs.logs.input_table import InputTableBuilder
from gcs.logs.logfile import InputError
from gcs.logs.ulog import UlogFile
from gcs.logs.ulog_format import SYNC
from gcs.runtime.replay import whole_table
from gcs.sessions.sources import ReplaySource, open_source, sample_frames

SHARED_ULOGS = sorted(p for p in LOGS.iterdir() if p.suffix.lower() == ".ulg")
PX4 = LOGS / "px4-flight-sample.ulg"


def message_starts(data: bytes) -> list[int]:
    """Offsets of the messages of an undamaged ULog (16-byte header, then uint16 size, type, body)."""
    starts, pos = [], 16
    while pos + 3 <= len(data):
        starts.append(pos)
        pos += 3 + int.from_bytes(data[pos : pos + 2], "little")
    assert pos == len(data)
    return starts


def assert_reads_like_pyulog(path, imu: int = 0) -> UlogFile:
    reference = pyulog_reference.read(str(path), imu)
    reader = UlogFile(str(path), imu)
    assert_same_samples(list(reader), reference.samples)
    assert dict(reader.counts) == reference.counts
    assert (reader.first_us, reader.last_us) == (reference.first_us, reference.last_us)
    return reader


@pytest.mark.parametrize("path", SHARED_ULOGS, ids=lambda p: p.name)
def test_every_shared_ulog_reads_as_pyulog_reads_it(path):
    reader = assert_reads_like_pyulog(path)
    assert reader.damage is None and reader.counts["sensor_combined"] > 10_000


#: The written flight: level, heading 60°, field 0.25 G north 0.40 G down, 3 m/s north-east.
YAW = math.radians(60.0)
FIELD_BODY = (0.25 * math.cos(YAW), -0.25 * math.sin(YAW), 0.40)
GPS_FIELDS = (
    "float vel_m_s;float vel_n_m_s;float vel_e_m_s;float vel_d_m_s;float cog_rad;uint8_t fix_type;bool vel_ned_valid"
)
CHANGE_US = 1_500_000


def written_flight(modern: bool) -> bytes:
    """PX4 ≥ 1.14 topics with EKF2_MAG_DECL (initial, changed, changed to a non-declination
    value) or older ones with GPS UTC time and no declination (the WMM then); both with a
    magnetometer at the IMU's timestamps, a GPS whose velocity is valid only sometimes and
    whose first fixes are 2D, and a vehicle_attitude with one timestamp out of order."""
    w = UlogWriter()
    if modern:
        w.param("EKF2_MAG_DECL", 10.0)
        w.param("MC_ROLL_P", 6.5)
    imu = "uint64_t timestamp;float[3] gyro_rad;uint32_t gyro_integral_dt;float[3] accelerometer_m_s2"
    w.topic("sensor_combined", imu)
    mag, gps = ("vehicle_magnetometer", "sensor_gps") if modern else ("sensor_mag", "vehicle_gps_position")
    field = "float[3] magnetometer_ga" if modern else "float x;float y;float z"
    w.topic(mag, f"uint64_t timestamp;{field}")
    position = (
        "double latitude_deg;double longitude_deg;double altitude_msl_m"
        if modern
        else "int32_t lat;int32_t lon;int32_t alt"
    )
    w.topic(gps, f"uint64_t timestamp;uint64_t time_utc_usec;{position};{GPS_FIELDS}")
    w.topic("vehicle_attitude", "uint64_t timestamp;float[4] q")
    rng = np.random.default_rng(7)
    for k in range(400):
        t = 1_000_000 + 5_000 * k
        if k % 4 == 0:
            field = tuple(float(v) for v in np.float32(FIELD_BODY) + np.float32(rng.normal(0, 0.01, 3)))
            w.add(mag, timestamp=t, **({"magnetometer_ga": field} if modern else dict(zip("xyz", field, strict=True))))
        gyro, accel = rng.normal(0, 0.02, 3), (0.0, 0.0, -9.80665) + rng.normal(0, 0.1, 3)
        w.add("sensor_combined", timestamp=t, gyro_rad=gyro, gyro_integral_dt=5000, accelerometer_m_s2=accel)
        if k % 10 == 3:
            half = math.radians(30.0) + float(rng.normal(0, 0.01))
            q = (math.cos(half), 0.0, 0.0, math.sin(half))
            w.add("vehicle_attitude", timestamp=t - (60_000 if k == 53 else 0), q=q)
        if modern and t in (CHANGE_US, CHANGE_US + 250_000):
            w.param("EKF2_MAG_DECL" if t == CHANGE_US else "MC_ROLL_P", 20.0 if t == CHANGE_US else 7.0)
        if k % 40 == 0:
            where = (
                {"latitude_deg": -35.3632610 + 1e-6 * k, "longitude_deg": 149.1652299, "altitude_msl_m": 584.09}
                if modern
                else {"lat": -353632610 + k, "lon": 1491652299, "alt": 584090}
            )
            vn, ve = 3.0 * math.cos(math.radians(45)), 3.0 * math.sin(math.radians(45))
            w.add(gps, timestamp=t, time_utc_usec=1_764_000_000_000_000 + t, **where, vel_m_s=3.0, vel_n_m_s=vn,
                  vel_e_m_s=ve, vel_d_m_s=0.1, cog_rad=math.radians(45), fix_type=2 if k < 80 else 3,
                  vel_ned_valid=k % 80 != 40)  # fmt: skip
    return w.bytes()


@pytest.mark.parametrize("modern", [True, False], ids=["px4-1.14", "older"])
def test_written_logs_read_as_pyulog_reads_them(tmp_path, modern):
    path = tmp_path / "flight.ulg"
    path.write_bytes(written_flight(modern))
    reader = assert_reads_like_pyulog(path)
    samples = list(UlogFile(str(path)))
    changes = [s.value for s in samples if isinstance(s, GainChange)]
    assert len(changes) == (2 if modern else 1) and reader.notes == []  # the fixture exercises what it should


def test_the_imu_instance_asked_for_or_a_clear_error(tmp_path):
    path = tmp_path / "flight.ulg"
    path.write_bytes(written_flight(True))
    with pytest.raises(InputError, match=r"offset 0: no sensor_combined instance 1 \(instances in the log: 0\)"):
        UlogFile(str(path), imu=1).columns()


def test_replay_fast_estimates_as_from_pyulogs_samples(logs_dir):
    """whole_table (what `gcs replay --fast` prints) over the columns equals it over an input
    table built from pyulog's samples, row for row; the frames are one per sample as before."""
    reference = pyulog_reference.read(str(PX4))
    table = InputTableBuilder()
    frame_t, input_end = [], []
    for sample in reference.samples:
        table.append(sample)
        if not isinstance(sample, GainChange):
            frame_t.append(sample.t)
            input_end.append(len(table))
    input_end[-1] = len(table)
    built = table.build()
    source = open_source(PX4)
    assert_same_samples(list(source.inputs()), reference.samples)
    assert source.frames.t.tolist() == frame_t and source.frames.input_end.tolist() == input_end
    expected = ReplaySource(str(PX4), "ulog", sample_frames(built), built, reference.counts, None)
    names = registry.names()
    assert whole_table(source, names, {}) == whole_table(expected, names, {})


@pytest.mark.parametrize("where", [0.3, 0.999])
@pytest.mark.parametrize("inside", [1, 5])
def test_a_cut_log_reads_up_to_the_cut_message(tmp_path, where, inside, capsys):
    """Cut inside a message's header (1 of its 3 bytes) or body: the messages before it are read
    exactly as pyulog reads them, and one line names the cut message's offset."""
    data = PX4.read_bytes()
    starts = message_starts(data)
    k = int(len(starts) * where)
    path = tmp_path / "cut.ulg"
    path.write_bytes(data[: starts[k] + inside])
    reader = assert_reads_like_pyulog(path)
    length = 3 if inside < 3 else 3 + int.from_bytes(data[starts[k] : starts[k] + 2], "little")
    assert reader.damage == (
        f"{path}: offset {starts[k]}: log ends inside a message ({inside} of its {length} bytes); "
        "samples up to there are used"
    )
    assert main(["replay", str(path), "--fast"]) == 0
    err = capsys.readouterr().err.splitlines()
    assert [line for line in err if line.startswith("damage")] == [f"damage: {reader.damage}"]


def test_a_damaged_header_stops_the_reading_there(tmp_path, capsys):
    """A message header zeroed half way: the samples before it are those of the file cut there
    (pyulog's), and `gcs replay` and `gcs estimate` say where and why in one line."""
    data = bytearray(PX4.read_bytes())
    at = message_starts(bytes(data))[len(message_starts(bytes(data))) // 2]
    data[at : at + 3] = bytes(3)
    path, before = tmp_path / "damaged.ulg", tmp_path / "before.ulg"
    path.write_bytes(bytes(data))
    before.write_bytes(bytes(data[:at]))
    reference = pyulog_reference.read(str(before))
    reader = UlogFile(str(path))
    assert_same_samples(list(reader), reference.samples)
    cause = "damaged data (message type 0x00, 0 bytes); samples up to there are used"
    assert reader.damage == f"{path}: offset {at}: {cause}"
    assert main(["replay", str(path), "--fast"]) == 0
    assert [line for line in capsys.readouterr().err.splitlines() if line.startswith("damage")] == [
        f"damage: {reader.damage}"
    ]
    out = tmp_path / "out.csv"
    assert main(["estimate", str(path), "-e", "dcm", "-o", str(out)]) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("gcs estimate: damage")]
    assert err == [f"gcs estimate: damage: {reader.damage}"]


def test_reading_resumes_at_a_sync_marker_after_damage(tmp_path):
    """Garbage, then a sync message ('S', the 8 sync bytes), then the rest of the log: the
    samples on both sides are read, the damage line says what was skipped."""
    data = PX4.read_bytes()
    starts = message_starts(data)
    k = len(starts) // 2
    sync = struct.pack("<HB", len(SYNC), ord("S")) + SYNC
    garbage = bytes(5)
    path = tmp_path / "resynced.ulg"
    path.write_bytes(data[: starts[k]] + garbage + sync + data[starts[k] :])
    reader = UlogFile(str(path))
    samples = list(reader)
    assert_same_samples(samples, pyulog_reference.read(str(PX4)).samples)
    resume = starts[k] + len(garbage) + len(sync)
    assert reader.damage == (
        f"{path}: offset {starts[k]}: damaged data (message type 0x00, 0 bytes); "
        f"skipped to the sync marker ending at offset {resume}"
    )


def test_many_short_messages_are_all_walked(tmp_path):
    """200,000 one-byte messages of a type the format does not know (a newer logger's) in the
    middle of the flight: more messages than the index is first sized for. They are skipped, every
    sample on both sides is read, and nothing is damage."""
    data = PX4.read_bytes()
    starts = message_starts(data)
    k = len(starts) // 2
    path = tmp_path / "short-messages.ulg"
    path.write_bytes(data[: starts[k]] + struct.pack("<HBB", 1, ord("x"), 0) * 200_000 + data[starts[k] :])
    reader = UlogFile(str(path))
    assert_same_samples(list(reader), pyulog_reference.read(str(PX4)).samples)
    assert reader.damage is None


def test_data_of_an_undeclared_message_id_is_skipped_as_pyulog_skips_it(tmp_path):
    """One sensor_combined message's id changed to one no subscription declared: that sample is
    gone, every other one is pyulog's (which skips it too), and the damage line names it."""
    data = bytearray(written_flight(True))
    starts = message_starts(bytes(data))
    data_messages = [s for s in starts if data[s + 2] == ord("D") and data[s + 3] == 0]  # msg_id 0: sensor_combined
    at = data_messages[100]
    data[at + 3 : at + 5] = struct.pack("<H", 99)
    path = tmp_path / "flight.ulg"
    path.write_bytes(bytes(data))
    reader = assert_reads_like_pyulog(path)
    assert reader.counts["sensor_combined"] == len(data_messages) - 1
    assert reader.damage == f"{path}: offset {at}: data for message id 99, which no subscription declared; skipped"


def test_a_data_message_of_the_wrong_size_is_skipped_as_pyulog_skips_it(tmp_path):
    """A vehicle_attitude message with 4 bytes more than its format: skipped by both readers."""
    w = UlogWriter()
    w.topic("sensor_combined", "uint64_t timestamp;float[3] gyro_rad;float[3] accelerometer_m_s2")
    w.topic("vehicle_attitude", "uint64_t timestamp;float[4] q")
    for k in range(50):
        t = 1_000_000 + 10_000 * k
        w.add("sensor_combined", timestamp=t, gyro_rad=(0.0, 0.01, 0.0), accelerometer_m_s2=(0.0, 0.0, -9.8))
        w.add("vehicle_attitude", timestamp=t, q=(1.0, 0.0, 0.0, 0.0))
    data = bytearray(w.bytes())
    at = [s for s in message_starts(bytes(data)) if data[s + 2] == ord("D") and data[s + 3] == 1][20]
    size = int.from_bytes(data[at : at + 2], "little")
    data[at : at + 2] = struct.pack("<H", size + 4)
    data[at + 3 + size : at + 3 + size] = bytes(4)
    path = tmp_path / "long.ulg"
    path.write_bytes(bytes(data))
    reader = assert_reads_like_pyulog(path)
    assert reader.counts == {"sensor_combined": 50, "vehicle_attitude": 49}
    cause = "vehicle_attitude message of 28 bytes where its format has 24; skipped"
    assert reader.damage == f"{path}: offset {at}: {cause}"


def with_flag_bits(data: bytes, incompat: bytes, appended: int = 0) -> bytes:
    """The log with a flag bits message first (the sample log, from before PX4 wrote one, has none)."""
    assert data[16 + 2] != ord("B")
    flags = bytes(8) + incompat.ljust(8, b"\0") + struct.pack("<3Q", appended, 0, 0)
    return data[:16] + struct.pack("<HB", len(flags), ord("B")) + flags + data[16:]


def test_appended_data_is_read_on_from_its_offset(tmp_path):
    """The flag bits' appended-data offset: the part before it ends in a half-written message
    (dropped), reading goes on at the offset with the subscriptions made before it, so the log
    gives every sample of the whole flight. (pyulog 1.3 drops its subscriptions at the end of the
    first part and loses the data after the offset: the reference here is the unsplit log.)"""
    data = PX4.read_bytes()
    starts = message_starts(data)
    k = len(starts) // 2
    half = data[: starts[k] + 7]
    path = tmp_path / "appended.ulg"
    path.write_bytes(with_flag_bits(half, b"\1", appended=len(half) + 43) + data[starts[k] :])
    reader = UlogFile(str(path))
    reference = pyulog_reference.read(str(PX4))
    assert_same_samples(list(reader), reference.samples)
    assert reader.damage is None and dict(reader.counts) == reference.counts
    assert pyulog_reference.read(str(path)).counts["sensor_combined"] < reference.counts["sensor_combined"]


def test_not_a_ulog_or_an_unknown_incompatible_flag_is_a_clear_error(tmp_path):
    path = tmp_path / "future.ulg"
    path.write_bytes(with_flag_bits(PX4.read_bytes(), b"\0\1"))  # incompat_flags[1]: a feature unknown here
    with pytest.raises(InputError, match=r"offset 0: not a ULog file \(unknown incompatible flag set\)"):
        UlogFile(str(path)).columns()
    path.write_bytes(b"ULog")
    with pytest.raises(InputError, match="offset 0: not a ULog file"):
        UlogFile(str(path)).columns()


def test_a_format_with_more_fields_than_a_message_holds_is_damage_not_a_hang(tmp_path):
    """sensor_combined declared as 65535 nested structs of 65535 floats (4 billion field names
    if spelled out): refused at once as damage, and no IMU topic is left."""

    def message(kind: str, payload: bytes) -> bytes:
        return struct.pack("<HB", len(payload), ord(kind)) + payload

    path = tmp_path / "huge.ulg"
    path.write_bytes(
        b"ULog\x01\x12\x35\x01" + bytes(8)
        + message("F", b"big:float[65535] v;")
        + message("F", b"sensor_combined:uint64_t timestamp;big[65535] x;")
        + message("A", struct.pack("<BH", 0, 0) + b"sensor_combined")
        + message("D", struct.pack("<HQ", 0, 1_000_000))
    )  # fmt: skip
    reader = UlogFile(str(path))
    with pytest.raises(InputError, match=r"no sensor_combined instance 0 \(none\)"):
        reader.columns()
    assert reader.damage is not None and "sensor_combined has no usable format" in reader.damage
    assert "more fields than a message has bytes" in reader.damage
