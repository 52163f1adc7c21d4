"""Every real log replays through the estimators; what the replay read matches pymavlink's and
pyulog's own readers (counts per type, time span); damage is reported with its byte offset."""

from __future__ import annotations

import math
import re
import struct
import subprocess
import sys
from collections import Counter

import numpy as np
import pytest
from pymavlink import mavutil
from pyulog import ULog

from gcs.batch.sweep import score_flight
from gcs.commands.cli import main
from gcs.logs.dataflash import TYPES
from gcs.logs.readers import InputError
from gcs.logs.ulog import ATTITUDE_TOPIC, IMU_TOPIC
from gcs.mavlink.sampling import IMU_TYPES
from gcs.mavlink.tlog import read_tlog_records
from gcs.runtime.replay import ReplaySession, session_table, whole_table
from gcs.sessions.sources import open_source
from gcs.sessions.whatif import run_estimator
from gcs.sim.dataflash import NEW_FORMATS, DataflashWriter

NAMES = ("dcm", "kf", "ekf")


def _replay(source) -> ReplaySession:
    session = ReplaySession(source, speed=0)
    session.run_to_end()
    return session


@pytest.mark.parametrize("name", ["arducopter-sitl-hop.tlog", "arduplane-sitl-vtol.tlog"])
def test_tlog_counts_and_span_match_pymavlink(logs_dir, name):
    path = str(logs_dir / name)
    conn = mavutil.mavlink_connection(path, robust_parsing=True)
    counts, stamps = Counter(), []
    while (msg := conn.recv_msg()) is not None:
        counts[msg.get_type()] += 1
        stamps.append(msg._timestamp)
    source = open_source(path)
    assert source.counts == dict(counts)
    assert source.span == pytest.approx((stamps[0], stamps[-1]), abs=1e-6)
    assert source.damage is None
    session = _replay(source)
    assert session.pipeline.imu_samples > 0
    assert all(c.summary()["references"] for c in session.pipeline.comparisons.values())


def test_low_rate_tlog_is_flagged_unreliable(logs_dir, capsys):
    """In the pipeline's comparison, and by `gcs replay` under its table (it printed the table
    alone, as if the errors were a fair comparison); a 248 Hz log gets no such note."""
    path = logs_dir / "arduplane-sitl-vtol.tlog"
    session = _replay(open_source(path))
    reliable, reason = session.pipeline.comparisons["dcm"].reliability()
    assert not reliable and "Hz" in reason
    assert main(["replay", str(path), "--fast"]) == 0
    notes = [line for line in capsys.readouterr().err.splitlines() if line.startswith("gcs replay: note: ")]
    assert len(notes) == 1 and "below the 50 Hz needed" in notes[0] and "not a fair comparison" in notes[0], notes
    assert main(["replay", str(logs_dir / "px4-flight-sample.ulg"), "--fast"]) == 0
    assert "Hz needed" not in capsys.readouterr().err  # its note is of the GPS it lacks, none of a rate


def _instance(record) -> int:
    """New logs: the I field; old ones: a sensor type's digit (IMU2 is the second IMU, instance 1)."""
    name = record.get_type()
    numbered = name[:3] in ("IMU", "MAG", "GPS") and name[3:].isdigit()
    return getattr(record, "I", int(name[3:]) - 1 if numbered else 0)


@pytest.mark.parametrize("name", ["arducopter-sitl-hop.BIN", "ardupilot-fragment.bin"])
def test_dataflash_counts_and_span_match_pymavlink(logs_dir, name):
    path = str(logs_dir / name)
    log = mavutil.mavlink_connection(path)
    counts, first, last = Counter(), None, None
    while (record := log.recv_msg()) is not None:  # a full pass, as mavlogdump does
        if record.get_type() in TYPES and _instance(record) == 0:
            counts[record.get_type()] += 1
            first = record.TimeUS if first is None else first
            last = record.TimeUS
    source = open_source(path)
    assert source.counts == dict(counts)
    assert source.span == (first / 1e6, last / 1e6)
    session = _replay(source)
    assert session.pipeline.imu_samples == counts["IMU"]
    assert set(session.pipeline.latest) >= {"onboard", "ahrs2", "dcm", "kf", "ekf"}


def test_truncated_dataflash_replays_up_to_the_damage_and_says_where(logs_dir, capsys):
    path = str(logs_dir / "ardupilot-fragment.bin")
    assert open_source(path).damage.startswith(f"{path}: offset 65512: log ends inside a record (24 of its 45 bytes)")
    assert main(["replay", path, "--fast"]) == 0
    printed = capsys.readouterr()
    assert "offset 65512" in printed.err
    # the printed speed is end to end, from the file to the table: its parts add up to the time it
    # is computed from; the process's start-up is printed apart, with the speed counting it too
    found = re.search(
        r"replayed ([0-9.]+) s in ([0-9.]+) s \(([0-9.]+)x real time, end to end: decoding ([0-9.]+) s, "
        r"estimators ([0-9.]+) s\); start-up ([0-9.]+) s \(numba's set-up and compiled kernels; "
        r"([0-9.]+)x real time with it\)",
        printed.out,
    )
    assert found, printed.out
    duration, total, speed, decoding, estimators, start_up, overall = map(float, found.groups())
    assert abs(decoding + estimators - total) <= 0.02  # each printed to 0.01 s
    assert within(speed, duration, total) and within(overall, duration, total + start_up, terms=2)
    assert overall <= speed  # equal as printed when the start-up rounds to 0 (kernels already loaded in-process)


def within(speed: float, duration: float, seconds: float, terms: int = 1) -> bool:
    """speed is duration / seconds, as printed: duration to 0.1 s, seconds a sum of `terms` values
    each printed to 0.01 s (so each off by up to 0.005 s)."""
    off = 0.005 * terms
    slowest, fastest = (duration - 0.05) / (seconds + off), (duration + 0.05) / max(seconds - off, 1e-9)
    return slowest - 0.05 <= speed <= fastest + 0.05


def test_a_dataflash_log_names_its_vehicle_only_as_far_as_it_says(hop_logs, tmp_path):
    """The hop's samples alone say nothing of the vehicle (no vehicle in the meta, "unknown" in a
    dataset); an ArduCopter banner says ArduPilot and its firmware but neither type nor id ("?");
    FRAME_CLASS 2 and SYSID_THISMAV 7 then say a hexarotor numbered 7."""
    folder, _ = hop_logs
    samples = (folder / "new.bin").read_bytes()
    assert open_source(folder / "new.bin").meta == {}
    told = DataflashWriter()  # the same type ids as new.bin's, and MSG
    for name, (fmt, columns) in NEW_FORMATS.items():
        told.define(name, fmt, columns)
    told.define("MSG", "QZ", "TimeUS,Message", 200)
    told.add("MSG", 0, b"ArduCopter V4.5.7 (2a3dc4b7)")
    (tmp_path / "banner.bin").write_bytes(told.bytes() + samples)
    firmware = "ArduCopter 4.5.7 (2a3dc4b7)"
    assert open_source(tmp_path / "banner.bin").meta == {"vehicle": {"label": "ArduPilot-?-?", "firmware": firmware}}
    told.add("PARM", 0, b"FRAME_CLASS", 2.0)
    told.add("PARM", 0, b"SYSID_THISMAV", 7.0)
    (tmp_path / "params.bin").write_bytes(told.bytes() + samples)
    told_all = {"vehicle": {"label": "ArduPilot-HEXAROTOR-7", "firmware": firmware}}
    assert open_source(tmp_path / "params.bin").meta == told_all


def test_ulog_counts_and_span_match_pyulog(logs_dir):
    path = str(logs_dir / "px4-flight-sample.ulg")
    topics = {d.name: d.data["timestamp"] for d in ULog(path).data_list if d.multi_id == 0}
    source = open_source(path)
    assert source.counts == {IMU_TOPIC: len(topics[IMU_TOPIC]), ATTITUDE_TOPIC: len(topics[ATTITUDE_TOPIC])}
    first = min(topics[IMU_TOPIC][0], topics[ATTITUDE_TOPIC][0])
    last = max(topics[IMU_TOPIC][-1], topics[ATTITUDE_TOPIC][-1])
    assert source.span == (first / 1e6, last / 1e6)
    session = _replay(source)
    assert session.pipeline.imu_samples == len(topics[IMU_TOPIC])
    rms = session.pipeline.comparisons["dcm"].summary()["references"]["onboard"]["session"]["rms"]
    assert rms[0] < 5 and rms[1] < 5  # roll, pitch against PX4's attitude_estimator_q, degrees


@pytest.mark.parametrize("suffix", [".tlog", ".bin", ".ulg"])
def test_garbage_is_a_clear_error(tmp_path, suffix, capsys):
    path = tmp_path / f"junk{suffix}"
    path.write_bytes(bytes(range(256)) * 8)
    with pytest.raises(InputError, match=str(path)):
        open_source(path)
    assert main(["replay", str(path), "--fast"]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "offset" in err and "Traceback" not in err


def test_estimate_accepts_bin_and_ulg(logs_dir, tmp_path):
    for name in ("arducopter-sitl-hop.BIN", "px4-flight-sample.ulg"):
        out = tmp_path / f"{name}.csv"
        assert main(["estimate", str(logs_dir / name), "-e", "dcm", "--out", str(out)]) == 0
        assert len(out.read_text().splitlines()) > 2000


def test_px4_flight_estimators_follow_onboard_roll_and_pitch(logs_dir):
    """A real PX4 flight (sensor_combined at 248 Hz) against its onboard vehicle_attitude, from
    attitude_estimator_q (SYS_MC_EST_GROUP 1, ATT_* and LPE_* parameters, no EKF2; not EKF2 as
    this test once said). The log has no magnetometer or GPS topics, so yaw has no common
    reference: only roll and pitch are compared."""
    session = ReplaySession(open_source(logs_dir / "px4-flight-sample.ulg"), speed=0)
    session.run_to_end()
    limits = {"ekf": 0.5, "dcm": 1.0, "kf": 1.0}  # RMS degrees
    for name, limit in limits.items():
        onboard = session.pipeline.summary()["estimators"][name]["comparison"]["references"]["onboard"]["session"]
        roll, pitch, _ = onboard["rms"]
        assert onboard["n"] > 6000
        assert roll < limit and pitch < limit, f"{name}: roll/pitch RMS {roll:.2f}/{pitch:.2f} deg vs onboard"


def ulog_message_starts(data: bytes) -> list[int]:
    """Offsets of the messages of an undamaged ULog: a 16-byte file header, then each message a
    3-byte header (uint16 body size, uint8 type) and its body (the ULog file format)."""
    starts, pos = [], 16
    while pos + 3 <= len(data):
        starts.append(pos)
        pos += 3 + int.from_bytes(data[pos : pos + 2], "little")
    assert pos == len(data), "the sample log itself is damaged"
    return starts


@pytest.mark.parametrize("where", [0.5, 0.999])
def test_truncated_ulog_replays_up_to_the_damage_and_says_where(logs_dir, tmp_path, where, capsys):
    data = (logs_dir / "px4-flight-sample.ulg").read_bytes()
    starts = ulog_message_starts(data)
    k = int(len(starts) * where)
    cut = starts[k] + 5  # inside message k
    path = tmp_path / "cut.ulg"
    path.write_bytes(data[:cut])
    source = open_source(path)
    assert source.damage.startswith(f"{path}: offset {starts[k]}: log ends inside a message (5 of its "), source.damage
    assert source.counts["sensor_combined"] > 0
    assert open_source(logs_dir / "px4-flight-sample.ulg").damage is None
    assert main(["replay", str(path), "--fast"]) == 0
    assert f"offset {starts[k]}" in capsys.readouterr().err


def test_dataflash_with_a_garbled_header_says_where_in_one_line(logs_dir, tmp_path, capfd):
    """One line for the damage, on file descriptor 2 too (capfd: nothing else is printed there)."""
    data = bytearray((logs_dir / "arducopter-sitl-hop.BIN").read_bytes())
    at = data.index(b"\xa3\x95", len(data) // 2)  # a record's header, half way through
    size = data.index(b"\xa3\x95", at + 2) - at
    data[at : at + 2] = b"\x00\x00"
    path = tmp_path / "garbled.bin"
    path.write_bytes(bytes(data))
    cause = f"bad record header 0x0000; {size} bytes skipped up to the next record"
    assert open_source(path).damage == f"{path}: offset {at}: {cause} (1 more damaged places)"  # and the cut end
    assert main(["replay", str(path), "--fast"]) == 0
    err = capfd.readouterr().err
    assert [line for line in err.splitlines() if "offset" in line] == [
        f"damage: {path}: offset {at}: {cause} (1 more damaged places)"
    ]


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["-g", "dmc.kp_rp=0.3"], "--gain 'dmc.kp_rp=0.3': 'dmc' is not a selected estimator (dcm, kf, ekf)"),
        (["-e", "kf", "-g", "dcm.kp_rp=0.3"], "--gain 'dcm.kp_rp=0.3': 'dcm' is not a selected estimator (kf)"),
    ],
)
def test_a_gain_for_an_estimator_not_replayed_is_refused(logs_dir, argv, expected, capsys):
    """`-g EST.NAME=VALUE` for a mistyped or unselected estimator was dropped without a word, and
    the table printed as if the gain had been tried (found by auditing `gcs replay -g nosuch.kp_rp=0.3`)."""
    assert main(["replay", str(logs_dir / "ardupilot-fragment.bin"), "--fast", *argv]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [f"gcs replay: error: {expected}"]


def _replay_cli(*argv: str) -> tuple[list[str], float]:
    """`gcs replay ARGV` in its own process: its error table's rows and the "x real time" it printed."""
    done = subprocess.run([sys.executable, "-m", "gcs", "replay", *argv], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    speed = re.search(r"\(([0-9.]+)x real time, end to end", done.stdout)
    assert speed, done.stdout
    return [line for line in lines if line.startswith(("dcm", "kf", "ekf"))], float(speed[1])


def test_fast_and_paced_replays_print_one_table_where_the_clock_steps_back(logs_dir):
    """The VTOL tlog's IMU clock steps back 1 s near its start: the pipeline (paced replays,
    reports, gcs batch) starts its comparison afresh there, as at a reboot, while `--fast`'s
    whole runs scored every reference against one run taken for time-ordered (an `onboard` row of
    n = 1 the others have not, truth n 887 against 883, other RMS)."""
    path = str(logs_dir / "arduplane-sitl-vtol.tlog")
    assert (np.diff(open_source(path).table.imu[:, 0]) < 0).any()
    fast, _ = _replay_cli(path, "--fast", "-e", "ekf")
    paced, _ = _replay_cli(path, "--speed", "1000", "-e", "ekf")
    assert len(fast) >= 3 and fast == paced


def test_what_if_and_the_sweep_score_where_the_clock_steps_back_as_the_replay(logs_dir):
    """What-if's runs and a sweep's flight scores (gcs.sessions.whatif.run_estimator) on the VTOL
    tlog scored every reference against one run of outputs taken for time-ordered: an `onboard`
    row (n = 1) the replay has not, and ahrs2 RMS 4.9852/4.2102/10.3767° where `gcs replay`
    (paced and --fast) reads 4.9855/4.2105/10.3855°. They now score as the pipeline does."""
    path = str(logs_dir / "arduplane-sitl-vtol.tlog")
    session = ReplaySession(open_source(path), speed=0, estimators=list(NAMES))
    session.run_to_end()
    paced = {(r["estimator"], r["reference"]): r for r in session_table(session.pipeline)}
    fast = {(r["estimator"], r["reference"]): r for r in whole_table(open_source(path), list(NAMES), {})[0]}
    assert fast.keys() == paced.keys()
    for name in NAMES:
        errors = run_estimator(open_source(path), name, {}).errors
        assert set(errors) == {ref for est, ref in paced if est == name}, name
        for ref, error in errors.items():
            for row in (paced[name, ref], fast[name, ref]):
                assert error["rms"] == pytest.approx(row["rms_deg"], rel=1e-9, abs=1e-12), (name, ref)
                assert error["max"] == pytest.approx(row["max_deg"], rel=1e-9, abs=1e-12), (name, ref)
        (score,) = score_flight(path, name, "truth", [{}]).scores
        rms = paced[name, "truth"]["rms_deg"]
        assert score == pytest.approx(math.sqrt(sum(v * v for v in rms) / 3), rel=1e-9), name


def test_a_paced_replay_ends_when_the_log_does(logs_dir):
    """`--speed 100` over the VTOL tlog's 207.6 s is 2.1 s: the end was seen by a once-a-second
    sleep, at 3 s, and the printed speed said 69x real time."""
    _, speed = _replay_cli(str(logs_dir / "arduplane-sitl-vtol.tlog"), "--speed", "100", "-e", "dcm")
    assert 85 <= speed <= 101, speed


def test_a_ulog_cut_in_its_definitions_says_where_it_ends(logs_dir, tmp_path):
    """A download cut inside the formats and subscriptions: the one line said only "offset 0: no
    sensor_combined instance 0 (none)", as for a log that never had the topic (found by the audit);
    it names where the file ends first, as a DataFlash log's does."""
    data = (logs_dir / "px4-flight-sample.ulg").read_bytes()
    at = ulog_message_starts(data)[3]  # the fourth message: still a definition
    size = 3 + int.from_bytes(data[at : at + 2], "little")
    path = tmp_path / "cut.ulg"
    path.write_bytes(data[: at + 5])
    cut = f"offset {at}: log ends inside a message (5 of its {size} bytes); samples up to there are used"
    for command in (["replay", "--fast"], ["estimate", "-e", "dcm", "--out", str(tmp_path / "o.csv")]):
        done = subprocess.run(
            [sys.executable, "-m", "gcs", command[0], str(path), *command[1:]],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert done.returncode == 2
        expected = f"gcs {command[0]}: error: {path}: {cut}; no sensor_combined instance 0 (none)"
        assert done.stderr.strip().splitlines() == [expected], done.stderr


def test_a_reference_that_is_no_number_is_left_out_of_the_fast_table_too(logs_dir, tmp_path):
    """Three ATT records of the hop's .BIN with a NaN roll (a damaged log): the pipeline refuses
    them (gcs.core.plausibility) and scores the rest, but `--fast`'s whole runs scored them and
    printed nan for the onboard roll RMS and max (found by the audit)."""
    data = bytearray((logs_dir / "arducopter-sitl-hop.BIN").read_bytes())
    fmt = data.index(b"ATT\0", data.index(b"\xa3\x95\x80")) - 5  # the FMT record: header, type, length, name
    kind, columns = data[fmt + 3], bytes(data[fmt + 25 : fmt + 89]).rstrip(b"\0").decode().split(",")
    assert bytes(data[fmt + 9 : fmt + 17]).rstrip(b"\0") == b"QffffffB" and columns[2] == "Roll"
    at = len(data) // 2
    for _ in range(3):
        at = data.index(bytes([0xA3, 0x95, kind]), at + 1)
        data[at + 3 + 8 + 4 : at + 3 + 8 + 8] = struct.pack("<f", math.nan)  # after TimeUS and DesRoll
    path = tmp_path / "nan-roll.bin"
    path.write_bytes(bytes(data))
    fast, _ = _replay_cli(str(path), "--fast", "-e", "dcm")
    paced, _ = _replay_cli(str(path), "--speed", "1000", "-e", "dcm")
    assert fast == paced and not any("nan" in row for row in fast), fast


def test_a_paced_replay_goes_past_a_damaged_timestamp(logs_dir, tmp_path):
    """One flipped bit in a tlog record's timestamp put that frame 68e9 s ahead: `gcs replay
    --speed 50` waited for it, silent, for ever (found by the audit). A frame due more than a
    minute of replay time away is played at once and the pacing goes on from the next."""
    data = bytearray((logs_dir / "arducopter-sitl-hop.tlog").read_bytes())
    offsets = [offset for offset, _, _ in read_tlog_records(logs_dir / "arducopter-sitl-hop.tlog").records()]
    stamp = offsets[len(offsets) // 2] - 8  # the record's 8-byte big-endian µs before its packet
    data[stamp : stamp + 8] = (int.from_bytes(data[stamp : stamp + 8], "big") ^ (1 << 56)).to_bytes(8, "big")
    path = tmp_path / "flipped-stamp.tlog"
    path.write_bytes(bytes(data))
    _, speed = _replay_cli(str(path), "--speed", "50", "-e", "dcm")
    assert 35 <= speed <= 51, speed


@pytest.mark.parametrize("cut", [False, True])
def test_a_tlog_without_imu_is_refused_by_replay_as_by_estimate(logs_dir, hop_without_imu, tmp_path, capsys, cut):
    """The hop's tlog without its IMU messages (88 s of everything else), or its first 1000 bytes
    (heartbeats, commands and one SCALED_IMU3, which gives no sample): `gcs replay` printed an
    empty table and a note, exit 0, where `gcs estimate` refused the same file, exit 2. Both
    refuse it in the same one line, exit 2, and write nothing."""
    path = hop_without_imu
    if cut:
        path = tmp_path / "no-imu.tlog"
        path.write_bytes((logs_dir / "arducopter-sitl-hop.tlog").read_bytes()[:1000])
        why = f"{path}: no IMU samples: nothing to estimate from"
    else:
        why = f"{path}: offset 0: no IMU message ({', '.join(IMU_TYPES)}) in the log: nothing to estimate from"
    out = tmp_path / "estimates.csv"
    for argv in (
        ["replay", "--fast", str(path)],
        ["replay", "--speed", "1000", str(path)],
        ["estimate", str(path), "-e", "dcm", "--out", str(out)],
    ):
        assert main(argv) == 2, argv
        printed, err = capsys.readouterr()
        assert printed == "" and err.splitlines()[-1:] == [f"gcs {argv[0]}: error: {why}"], err
    assert not out.exists()


def test_replay_and_report_say_what_the_log_lacks_as_estimate_does(logs_dir, tmp_path, capsys):
    """The PX4 log has no GPS topic: `gcs estimate` noted "no GPS aiding", but `gcs replay` and
    `gcs report` of the same log said nothing, and their errors went unexplained."""
    log = str(logs_dir / "px4-flight-sample.ulg")
    assert main(["estimate", log, "-e", "dcm", "--out", str(tmp_path / "est.csv")]) == 0
    notes = [line.split("note: ", 1)[1] for line in capsys.readouterr().err.splitlines() if " note: " in line]
    assert f"{log}: no sensor_gps or vehicle_gps_position topic: no GPS aiding" in notes
    assert main(["replay", "--fast", log]) == 0
    err = capsys.readouterr().err.splitlines()
    assert all(f"gcs replay: note: {note}" in err for note in notes)
    assert main(["report", log, "--out", str(tmp_path / "px4.html")]) == 0
    page = (tmp_path / "px4.html").read_text()
    assert all(f"<td>note</td><td>{note}</td>" in page for note in notes)


def test_a_ulogs_logging_dropouts_are_noted_as_pyulog_counts_them(logs_dir):
    """PX4's logger lost data four times in the sample flight ('O' messages: 119 ms, pyulog and
    Flight Review show them); replay, report and estimate said nothing of the gaps."""
    path = logs_dir / "px4-flight-sample.ulg"
    dropouts = [d.duration for d in ULog(str(path)).dropouts]
    assert len(dropouts) == 4
    source = open_source(path)
    (note,) = [n for n in source.notes if "dropouts" in n]
    assert note.startswith(
        f"{path}: 4 logging dropouts, {sum(dropouts)} ms of data lost (the longest {max(dropouts)} ms"
    )
