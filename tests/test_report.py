"""`gcs report` writes one self-contained HTML page; `gcs export` writes what it says."""

from __future__ import annotations

import fcntl
import os
import pty
import re
import select
import struct
import subprocess
import sys
import termios
import time

import numpy as np
import pyarrow.compute as pc
import pyarrow.csv as pcsv
import pyarrow.parquet as pq
import pytest
from pymavlink import mavutil

from gcs.commands.cli import main
from gcs.provenance import provenance


def test_report_of_dataflash_log(logs_dir, tmp_path, capsys):
    out = tmp_path / "hop.html"
    assert main(["report", str(logs_dir / "arducopter-sitl-hop.BIN"), "--out", str(out)]) == 0
    page = out.read_text()
    images = re.findall(r"<img src='data:image/png;base64,([A-Za-z0-9+/=]+)'>", page)
    assert len(images) == 2 and all(len(i) > 10_000 for i in images)  # attitude and errors vs truth
    assert "Errors against truth" in page
    for estimator in ("dcm", "kf", "ekf"):
        assert re.search(rf"<td>{estimator}</td><td>truth</td><td>980</td>", page)
    assert "<td>IMU</td><td>2450</td><td>25.0</td>" in page  # rates table
    assert "src='http" not in page and "<script" not in page  # self-contained
    assert capsys.readouterr().err == f"wrote {out}\n"  # no progress bar when stderr is not a terminal
    assert provenance().commit and provenance().commit.split("+")[0] in page  # which code made it


def test_report_of_tlog_shows_packet_loss(logs_dir, tmp_path):
    out = tmp_path / "vtol.html"
    assert main(["report", str(logs_dir / "arduplane-sitl-vtol.tlog"), "--out", str(out)]) == 0
    page = out.read_text()
    assert "lost (by sequence number)" in page and "cannot follow" in page  # 4 Hz IMU: flagged


def test_export_csv_and_parquet(logs_dir, tmp_path):
    csv_out, parquet_out = tmp_path / "a.csv", tmp_path / "a.parquet"
    log = str(logs_dir / "ardupilot-fragment.bin")
    assert main(["export", log, "--format", "csv", "--out", str(csv_out)]) == 0
    assert main(["export", log, "--format", "parquet", "--out", str(parquet_out)]) == 0
    table = pcsv.read_csv(csv_out)
    assert table.column_names == ["wall_time", "t", "source", "roll_deg", "pitch_deg", "yaw_deg"]
    parquet = pq.read_table(parquet_out)
    assert parquet.column_names == table.column_names and parquet.num_rows == table.num_rows > 100
    assert np.allclose(parquet.column("roll_deg").to_numpy(), table.column("roll_deg").to_numpy())
    assert set(table.column("source").to_pylist()) >= {"onboard", "ahrs2", "dcm"}
    # the DataFlash log has no host time: its wall times are missing (empty fields), not "nan"
    assert csv_out.read_text().splitlines()[1].startswith(",")
    assert table.column("wall_time").null_count == parquet.column("wall_time").null_count == table.num_rows


def test_export_of_missing_session_is_a_clear_error(tmp_path, capsys):
    assert main(["export", str(tmp_path / "nope"), "--out", str(tmp_path / "x.csv")]) == 2
    assert "nope: no such file or session folder" in capsys.readouterr().err


def test_progress_bar_on_a_terminal(logs_dir):
    """On a terminal (a pseudo-terminal here) replay shows a tqdm bar that reaches 100%."""
    main_fd, terminal = pty.openpty()
    fcntl.ioctl(terminal, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))  # a real terminal's size
    process = subprocess.Popen(
        [sys.executable, "-m", "gcs", "replay", str(logs_dir / "arducopter-sitl-hop.BIN"), "--fast", "-e", "dcm"],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=terminal,
    )
    os.close(terminal)
    seen = b""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        ready, _, _ = select.select([main_fd], [], [], 1.0)
        if ready:
            try:
                chunk = os.read(main_fd, 4096)
            except OSError:  # the terminal closed: the process has ended
                break
            if not chunk:
                break
            seen += chunk
    os.close(main_fd)
    assert process.wait(30) == 0
    assert b"replay: 100%" in seen, seen[-300:]


def test_report_lines_break_where_yaw_crosses_180_degrees(logs_dir):
    """The ArduPlane SITL VTOL flight turns through ±180° in yaw many times: each source's yaw line has a gap
    there (a NaN between the two samples), where a vertical bar used to cross the whole panel."""
    from gcs.sessions.report import attitude_figure, collect
    from gcs.sessions.sources import open_source

    series, _ = collect(open_source(logs_dir / "arduplane-sitl-vtol.tlog"))
    wraps = 0
    for line in attitude_figure(series).axes[2].lines:  # the yaw panel: one line per source
        yaw = np.asarray(line.get_ydata(), float)
        drawn = np.abs(np.diff(yaw))  # a step between two NaN-free neighbours is one drawn segment
        assert np.nanmax(drawn) < 180.0, line.get_label()
        wraps += int(np.isnan(yaw).sum())
    assert wraps > 0  # the flight does cross ±180°: the gaps are there


def test_export_of_a_tlog_carries_each_record_wall_time(logs_dir, tmp_path):
    """A .tlog stamps every record with the host's UNIX time, and the export's wall_time column
    promises it "for logs with host time"; a tlog's export left it empty. Each onboard row now
    carries the stamp of the ATTITUDE record it came from, as pymavlink's own tlog reader gives it
    (`_timestamp`), and every estimator row the stamp of its IMU record."""
    out = tmp_path / "hop.parquet"
    tlog = logs_dir / "arducopter-sitl-hop.tlog"
    assert main(["export", str(tlog), "--format", "parquet", "--out", str(out)]) == 0
    table = pq.read_table(out)
    assert table.column("wall_time").null_count == 0, table.column("wall_time").null_count
    stamps: dict[int, float] = {}  # ATTITUDE time_boot_ms → the record's stamp
    log = mavutil.mavlink_connection(str(tlog))
    while (msg := log.recv_match(type="ATTITUDE")) is not None:
        stamps.setdefault(msg.time_boot_ms, msg._timestamp)
    onboard = table.filter(pc.equal(table["source"], "onboard")).to_pydict()
    assert len(onboard["t"]) > 1000
    # the record's stamp as written (its two lowest bits carry the tlog's link flags: within 4 µs)
    worst = max(abs(w - stamps[round(1000 * t)]) for t, w in zip(onboard["t"], onboard["wall_time"], strict=True))
    assert worst < 5e-6, worst
    # the estimators' rows on the same clock: within one IMU interval (25 Hz) of the onboard rows
    dcm = table.filter(pc.equal(table["source"], "dcm")).to_pydict()
    offsets = np.subtract(dcm["wall_time"], dcm["t"])
    onboard_offset = np.median(np.subtract(onboard["wall_time"], onboard["t"]))
    assert np.ptp(offsets) < 1.0 and abs(np.median(offsets) - onboard_offset) < 0.04, (np.ptp(offsets), onboard_offset)


@pytest.mark.parametrize(
    "argv", [["report"], ["export"], ["export", "--format", "mat"]], ids=["report", "export-csv", "export-mat"]
)
def test_an_out_that_is_the_flight_log_itself_is_refused_and_the_log_kept(
    logs_dir, tmp_path, monkeypatch, argv, capsys
):
    """`gcs report flight.bin --out flight.bin` (a slip of the shell history) replaced the flight
    log with its own report: the recording was gone. The same file by another name (./x, a link)
    too."""
    log = tmp_path / "flight.bin"
    log.write_bytes((logs_dir / "ardupilot-fragment.bin").read_bytes())
    (tmp_path / "link.bin").symlink_to(log)
    monkeypatch.chdir(tmp_path)
    for out in ("flight.bin", "./flight.bin", "link.bin"):
        assert main([argv[0], "flight.bin", *argv[1:], "--out", out]) == 2
        assert capsys.readouterr().err == f"gcs {argv[0]}: error: --out {out} is the input itself; give another file\n"
    assert log.read_bytes() == (logs_dir / "ardupilot-fragment.bin").read_bytes()
