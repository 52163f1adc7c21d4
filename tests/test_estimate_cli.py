"""The `gcs estimate` contract: header, one row per IMU sample, --list, clear bad-input errors."""

import csv
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil
from synthetic import Z_UP, angle_between, spinning

from gcs.commands import estimate as offline
from gcs.core.rotation import euler_to_quat
from gcs.mavlink.tlog import read_tlog_records

LOGS = Path(__file__).resolve().parents[2] / "shared/data/logs"
HEADER = "t,qw,qx,qy,qz,roll,pitch,yaw"


def write_csv(path, samples, gps=None):
    cols = "t,gx,gy,gz,ax,ay,az,mx,my,mz" + (",vn,ve,vd" if gps is not None else "")
    with open(path, "w") as fh:
        fh.write(cols + "\n")
        for i, s in enumerate(samples):
            row = [s.t, *s.gyro, *s.accel, *(s.mag if s.mag is not None else ("", "", ""))]
            if gps is not None:
                row += list(gps[i])
            fh.write(",".join(str(v) for v in row) + "\n")


def estimate(*argv):
    return offline.main([str(a) for a in argv])


def read_out(path):
    with open(path) as fh:
        return fh.readline().strip(), list(csv.reader(fh))


@pytest.mark.parametrize("name", ["dcm", "kf"])
def test_csv_one_row_per_sample_in_a_z_up_frame(tmp_path, name):
    samples, _ = spinning(euler_to_quat(0.0, 0.0, 0.5), [0.0, 0.0, 0.2], rate=100, duration=2, frame=Z_UP)
    write_csv(tmp_path / "in.csv", samples)
    assert estimate(tmp_path / "in.csv", "--estimator", name, "--out", tmp_path / "out.csv") == 0
    header, rows = read_out(tmp_path / "out.csv")
    assert header == HEADER and len(rows) == len(samples)
    assert [float(r[0]) for r in rows] == pytest.approx([s.t for s in samples])
    # a z-up sensor lying level is rolled 180° relative to FRD
    assert abs(float(rows[-1][5])) == pytest.approx(180.0, abs=0.5)
    assert all(abs(np.linalg.norm([float(v) for v in r[1:5]]) - 1) < 1e-6 for r in rows)


def test_csv_with_gps_velocity_columns_and_gains(tmp_path):
    samples, _ = spinning(euler_to_quat(0.0, 0.0, 0.0), [0.0, 0.0, 0.0], rate=50, duration=2)
    gps = [("", "", "")] * 50 + [(1.0, 0.0, 0.0)] * 50
    write_csv(tmp_path / "in.csv", samples, gps)
    rc = estimate(
        tmp_path / "in.csv",
        "-e",
        "dcm",
        "--preset",
        "seed000",
        "--gain",
        "kp_rp=1.5",
        "--gain",
        "declination=0.1",
        "-o",
        tmp_path / "out.csv",
    )
    assert rc == 0
    _, rows = read_out(tmp_path / "out.csv")
    assert len(rows) == 100 and float(rows[-1][7]) == pytest.approx(math.degrees(0.1), abs=0.5)


def test_tlog_input(tmp_path):
    assert estimate(LOGS / "arducopter-sitl-hop.tlog", "-e", "dcm", "-o", tmp_path / "out.csv") == 0
    header, rows = read_out(tmp_path / "out.csv")
    assert header == HEADER and len(rows) == 2197  # RAW_IMU messages in the log


def test_tlog_imu_instance_1_is_the_second_imu(tmp_path):
    """Found by auditing an ArduPlane SITL session: `gcs estimate FLIGHT.tlog --imu 1` (and 2)
    wrote instance 0's attitude, byte for byte. Instance 1 of a .tlog is SCALED_IMU2, stamped in
    whole milliseconds (time_boot_ms) where RAW_IMU carries microseconds: the rows are its
    messages, as pymavlink reads them, and its estimate is not instance 0's."""
    hop = LOGS / "arducopter-sitl-hop.tlog"
    log = mavutil.mavlink_connection(str(hop))
    second = []
    while (msg := log.recv_match(type="SCALED_IMU2")) is not None:
        second.append(msg.time_boot_ms / 1e3)
    for imu in (0, 1):
        assert estimate(hop, "-e", "dcm", "--imu", imu, "-o", tmp_path / f"imu{imu}.csv") == 0
    _, first_rows = read_out(tmp_path / "imu0.csv")
    _, second_rows = read_out(tmp_path / "imu1.csv")
    t = np.array([float(row[0]) for row in second_rows])
    np.testing.assert_allclose(t, second, atol=5e-7)  # one row per SCALED_IMU2, at its time
    assert [row[0] for row in second_rows] != [row[0] for row in first_rows]


def test_list(capsys):
    assert estimate("--list") == 0
    out = capsys.readouterr().out
    for text in (
        "dcm:",
        "kf:",
        "ardupilot (default)",
        "seed000",
        "seed004",
        "kp_rp",
        "default 0.2",
        "[0, 50]",
        "1/s",
        "roll-pitch proportional gain",
        "declination",
    ):
        assert text in out
    # each estimator is described by what it is, not by a compiled class's docstring cut mid-sentence
    # (found by auditing: "dcm: `dcm` with its per-sample update compiled; ... health as")
    described = [line for line in out.splitlines() if not line.startswith(" ")]
    assert described == [
        "dcm: Direction cosine matrix filter with PI drift correction (Premerlani & Bizard 2009).",
        "kf: KF-A: linear Kalman filter on Euler angles and their rates (seed 004, §5.2.2).",
        "ekf: Error-state (multiplicative) Kalman filter of attitude, velocity and gyro bias.",
    ], described


@pytest.mark.parametrize(
    "content, expected",
    [
        (
            "t,gx,gy,gz,ax,ay,az,mx,my,mz\n0,0,0,0,0,0,-9.8,,,\n0.01,0,abc,0,0,0,-9.8,,,\n",
            "line 3: field 'gy': 'abc' is not a number",
        ),
        ("t,gx,gy,gz,ax,ay,az\n0,0,0,0,0,0,-9.8\n", "line 1: header lacks column(s) mx, my, mz"),
        ("t,gx,gy,gz,ax,ay,az,mx,my,mz\n0,0,0,0,0,0,nan,,,\n", "line 2: field 'az': 'nan' is not finite"),
        ("t,gx,gy,gz,ax,ay,az,mx,my,mz\n0,0,0,0,0,0,-9.8,1,,\n", "line 2: field 'mx'/'my'/'mz'"),
        ("t,gx,gy,gz,ax,ay,az,mx,my,mz\n0,0,0\n", "line 2: 3 fields, header has 10"),
        ("", "line 1: empty file"),
    ],
)
def test_bad_csv_is_a_clear_error(tmp_path, capsys, content, expected):
    (tmp_path / "bad.csv").write_text(content)
    assert estimate(tmp_path / "bad.csv", "-e", "dcm", "-o", tmp_path / "out.csv") == 2
    err = capsys.readouterr().err
    assert str(tmp_path / "bad.csv") in err and expected in err and "Traceback" not in err


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["missing.csv", "-e", "dcm", "-o", "OUT"], "missing.csv: no such file"),
        # a session folder: "no such file" (found by the audit) of a folder that is there
        (
            ["FOLDER", "-e", "dcm", "-o", "OUT"],
            "FOLDER: a folder, not a log file; give a .csv, .tlog, .bin, .log, .ulg file",
        ),
        (["IN", "-e", "nope", "-o", "OUT"], "unknown estimator 'nope'"),
        (["IN", "-e", "dcm", "-p", "nope", "-o", "OUT"], "unknown preset 'nope'"),
        (["IN", "-e", "dcm", "-g", "kp_rp=99", "-o", "OUT"], "gain kp_rp: 99 1/s is outside [0, 50]"),
        (["IN", "-e", "dcm", "-g", "kp_rp", "-o", "OUT"], "expected NAME=VALUE"),
        (["IN", "-e", "dcm", "-o", "OUT", "-g", "bogus=1"], "unknown gain 'bogus'"),
        (["IN.txt", "-e", "dcm", "-o", "OUT"], "unknown input format '.txt'"),
        (["IN", "-o", "OUT"], "--estimator is required"),
    ],
)
def test_bad_arguments_exit_2(tmp_path, capsys, argv, expected):
    (tmp_path / "IN").write_text("t,gx,gy,gz,ax,ay,az,mx,my,mz\n0,0,0,0,0,0,-9.8,,,\n")
    (tmp_path / "IN.txt").write_text("x")
    (tmp_path / "FOLDER").mkdir()
    argv = [str(tmp_path / a) if a in ("IN", "IN.txt", "OUT", "FOLDER") else a for a in argv]
    assert estimate(*argv) == 2
    assert expected in capsys.readouterr().err


def test_not_a_tlog_is_a_clear_error(tmp_path):
    bad = tmp_path / "junk.tlog"
    bad.write_bytes(bytes(range(256)) * 10)
    proc = subprocess.run(
        [sys.executable, "-m", "gcs.commands.estimate", str(bad), "-e", "dcm", "-o", str(tmp_path / "o.csv")],
        capture_output=True,
        text=True,
        cwd=Path(__file__).parents[1],
    )
    assert proc.returncode == 2
    assert f"{bad}: offset 0: no IMU message" in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.slow
def test_dcm_follows_five_minutes_at_285_hz(tmp_path):
    """A long run keeps one row per sample and stays on the true attitude (its speed is measured
    in bench/broad.py, not here: a timed test fails on a loaded machine for no reason)."""
    samples, truth = spinning(euler_to_quat(0.1, 0.2, 0.3), [0.1, -0.2, 0.3], rate=285.714, duration=300)
    write_csv(tmp_path / "in.csv", samples)
    assert estimate(tmp_path / "in.csv", "-e", "dcm", "-o", tmp_path / "out.csv") == 0
    _, rows = read_out(tmp_path / "out.csv")
    assert len(rows) == len(samples)
    q_end = np.array([float(v) for v in rows[-1][1:5]])
    assert angle_between(q_end, truth[-1]) < 2.0


def test_through_the_gcs_command(tmp_path):
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "gcs",
            "estimate",
            str(LOGS / "arducopter-sitl-hop.tlog"),
            "--estimator",
            "kf",
            "--out",
            str(tmp_path / "o.csv"),
        ],
        capture_output=True,
        text=True,
        cwd=Path(__file__).parents[1],
    )
    assert proc.returncode == 0, proc.stderr
    assert read_out(tmp_path / "o.csv")[0] == HEADER


def test_tlog_declination_is_applied_and_reported(tmp_path):
    """The hop tlog holds no COMPASS_DEC: `gcs estimate` refers its yaw to the WMM at the SITL home
    (12.69° at Canberra), says so on stderr, and a --gain declination wins over it; the same live
    and offline (the pipeline's MessageInputs)."""
    hop = LOGS / "arducopter-sitl-hop.tlog"
    runs = {}
    for label, extra in (("wmm", []), ("pinned", ["--gain", "declination=0"])):
        out = tmp_path / f"{label}.csv"
        proc = subprocess.run(
            [sys.executable, "-m", "gcs", "estimate", str(hop), "-e", "ekf", "-o", str(out), *extra],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert proc.returncode == 0, proc.stderr
        runs[label] = (proc.stderr.strip(), read_out(out)[1])
    assert runs["wmm"][0] == "gcs estimate: declination 12.69 deg from WMM at -35.3633,149.1652"
    assert runs["pinned"][0] == "gcs estimate: declination 0.00 deg from --gain declination"
    yaw_wmm, yaw_mag = float(runs["wmm"][1][-1][7]), float(runs["pinned"][1][-1][7])
    assert math.degrees(math.remainder(math.radians(yaw_wmm - yaw_mag), 2 * math.pi)) == pytest.approx(12.69, abs=1.0)


def test_a_spreadsheet_csv_with_a_byte_order_mark_is_read(tmp_path):
    """Excel's "CSV UTF-8" starts with a byte-order mark and ends its lines with CRLF; the header's
    `t` must not become '\\ufefft' (found by auditing: "header lacks column(s) t" for such a file)."""
    rows = ["t,gx,gy,gz,ax,ay,az,mx,my,mz", "0,0,0,0,0,0,-9.8,,,", "0.01,0,0,0,0,0,-9.8,,,"]
    (tmp_path / "excel.csv").write_bytes(b"\xef\xbb\xbf" + "\r\n".join(rows).encode() + b"\r\n")
    assert estimate(tmp_path / "excel.csv", "-e", "dcm", "-o", tmp_path / "out.csv") == 0
    assert read_out(tmp_path / "out.csv")[0] == HEADER and len(read_out(tmp_path / "out.csv")[1]) == 2


@pytest.mark.parametrize(
    "content, expected",
    [
        (bytes(range(128, 256)) * 40, "line 1: not UTF-8 text (byte 0x80); is this a CSV?"),
        (b"t,gx,gy,gz,ax,ay,az,mx,my,mz\n0,0,0,0,0,0,-9.8,,,\n\xff\xfe\n", "line 3: not UTF-8 text (byte 0xff)"),
        (b't,gx,gy,gz,ax,ay,az,mx,my,mz\n0,0,0,0,0,0,-9.8,,,\n"' + b"a" * 200_000 + b"\n", "line 3: field larger than"),
    ],
)
def test_a_binary_or_broken_csv_is_a_clear_error(tmp_path, capsys, content, expected):
    """Bytes that are not a CSV (a binary file named .csv) end in one line naming file and line,
    not a UnicodeDecodeError or csv.Error traceback (found by auditing with random bytes)."""
    (tmp_path / "bad.csv").write_bytes(content)
    keep = tmp_path / "out.csv"
    keep.write_text("earlier results\n")
    assert estimate(tmp_path / "bad.csv", "-e", "dcm", "-o", keep) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"gcs estimate: error: {tmp_path / 'bad.csv'}: ") and expected in err, err
    assert keep.read_text() == "earlier results\n"


def test_a_damaged_tlog_is_estimated_up_to_the_damage_and_says_where(tmp_path):
    """The contract's "one line on stderr saying where" for a .tlog too, as for .bin and .ulg: a
    copy of the hop cut mid-record, and one with junk bytes in the middle (found by auditing: a
    truncated .tlog was estimated with no word of the damage)."""
    hop = (LOGS / "arducopter-sitl-hop.tlog").read_bytes()
    cut = tmp_path / "cut.tlog"
    cut.write_bytes(hop[:300_000])
    records = read_tlog_records(LOGS / "arducopter-sitl-hop.tlog").records()
    at = next(offset - 8 for offset, _, _ in records if offset > 200_000)  # a record's first byte
    junk = tmp_path / "junk.tlog"
    junk.write_bytes(hop[:at] + b"\x00" * 100 + hop[at:])
    for log, expected in (
        (cut, f"gcs estimate: damage: {cut}: offset 299986: last record incomplete; estimated up to it"),
        (junk, f"gcs estimate: damage: {junk}: offset {at}: 100 damaged bytes skipped (1 places)"),
    ):
        proc = subprocess.run(
            [sys.executable, "-m", "gcs", "estimate", str(log), "-e", "dcm", "-o", str(tmp_path / "o.csv")],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert proc.returncode == 0, proc.stderr
        assert any(line.startswith(expected) for line in proc.stderr.splitlines()), proc.stderr
        assert len(read_out(tmp_path / "o.csv")[1]) > 100
