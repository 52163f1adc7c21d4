"""The `gcs` command as a user runs it: help, and `gcs status --json` against a simulator
running as a separate process."""

from __future__ import annotations

import json
import socket
import subprocess
import sys

from gcs.commands.cli import SUBCOMMANDS
from gcs.mavlink.tlog import read_tlog_records

GCS = [sys.executable, "-m", "gcs"]


def test_help_lists_every_subcommand_and_each_has_help():
    out = subprocess.run(GCS + ["--help"], capture_output=True, text=True, check=True).stdout
    for name in SUBCOMMANDS:
        assert name in out
        sub = subprocess.run(GCS + [name, "--help"], capture_output=True, text=True)
        assert sub.returncode == 0 and "usage:" in sub.stdout


def test_signing_setup_offers_no_option_it_would_ignore():
    """It records nothing and requests no streams: --record-dir, --no-record, --speed, the rates
    and the ascii options were listed in its help and silently ignored."""
    out = subprocess.run(GCS + ["signing", "setup", "--help"], capture_output=True, text=True, check=True).stdout
    assert "--signing-key" in out and "--connect" in out
    for ignored in ("--record-dir", "--no-record", "--speed", "--imu-rate", "--ascii-fields"):
        assert ignored not in out, ignored


def test_status_json_against_apm25_reports_requested_and_achieved_rates(udp_port):
    sim = subprocess.Popen(
        GCS + ["sim", "--profile", "apm25", "--link", f"udpout:127.0.0.1:{udp_port}"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        done = subprocess.run(
            GCS + ["status", "--connect", f"udpin:127.0.0.1:{udp_port}", "--duration", "8", "--json"],
            capture_output=True,
            text=True,
            timeout=60,
        )
    finally:
        sim.terminate()
        sim.wait(10)
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert report["vehicle"]["autopilot"] == "ArduPilot"
    assert report["vehicle"]["mavlink_version"] == 1
    assert report["streams"]["method"] == "REQUEST_DATA_STREAM"
    raw = report["streams"]["messages"]["RAW_IMU"]
    assert raw["requested_hz"] == 50.0
    assert 45.0 <= raw["achieved_hz"] <= 55.0
    assert report["link"]["stats"]["crc_errors"] == 0
    # each state change once (the shared link's and the vehicle's own were both listed)
    states = [e["detail"] for e in report["link"]["events"] if e["kind"] == "state"]
    assert states == ["waiting -> connected"], report["link"]["events"]


def test_status_rejects_a_bad_connection_string():
    done = subprocess.run(GCS + ["status", "--connect", "bogus:1:2"], capture_output=True, text=True)
    assert done.returncode == 2 and "unknown scheme" in done.stderr


def test_demo_shows_live_data_and_stops_on_ctrl_c():
    """The first command a user runs: the dashboard URL, then live link and estimator lines, and
    a clean stop on Ctrl-C. (How soon the first line comes is a speed, not checked here: a fixed
    --duration 10 failed on a loaded machine before the estimators had a second of data.)"""
    import queue
    import signal
    import threading
    import time

    from conftest import free_port

    port = free_port(socket.SOCK_STREAM)
    proc = subprocess.Popen(
        GCS + ["demo", "--no-record", "--port", str(port)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    lines: queue.Queue[str] = queue.Queue()
    reader = threading.Thread(target=lambda: [lines.put(line) for line in proc.stdout], daemon=True)
    reader.start()
    seen: list[str] = []
    deadline = time.monotonic() + 90
    try:
        # a line with the link's rates beside the estimators: the rates of a vehicle start when it
        # is identified, and need a second sample, so the first estimator lines may come without
        while not any(line.startswith("link connected") and "ekf" in line and "ATTITUDE" in line for line in seen):
            try:
                seen.append(lines.get(timeout=max(0.1, deadline - time.monotonic())))
            except queue.Empty:
                raise AssertionError(f"no live estimator line in 90 s:\n{''.join(seen)}") from None
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(60)
    assert proc.returncode == 0, proc.stderr.read()
    assert f"dashboard at http://127.0.0.1:{port}" in "".join(seen)
    assert "truth" in seen[-1], seen[-1]


def test_status_says_where_it_forwarded_and_how_many_packets(logs_dir, udp_port, tcp_port):
    """`--out` forwarded the link to other ground stations, but the report never named the
    outputs: whether Mission Planner behind one got anything could not be told, nor that a TCP
    output was never opened (its peer not listening)."""
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind(("127.0.0.1", udp_port))
    peer.settimeout(30)
    try:
        done = subprocess.run(
            GCS
            + ["status", "--connect", str(logs_dir / "arducopter-sitl-hop.tlog"), "--speed", "0"]
            + ["--duration", "5", "--out", f"udpout:127.0.0.1:{udp_port}", "--out", f"tcp:127.0.0.1:{tcp_port}"],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert peer.recv(300)  # the UDP output got packets
    finally:
        peer.close()
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    udp = next(line for line in lines if line.startswith(f"forward    udpout:127.0.0.1:{udp_port}  open  "))
    # every packet of the tlog: at --speed 0 it was read to its end before the output opened (0
    # sent), or its first reads were (31,130 of 31,386)
    packets = sum(1 for _ in read_tlog_records(logs_dir / "arducopter-sitl-hop.tlog"))
    assert int(udp.split("open")[1].split("packets sent")[0]) == packets, (udp, packets)
    assert f"forward    tcp:127.0.0.1:{tcp_port}  NOT OPEN (see events)  0 packets sent, 0 received" in lines


def test_status_on_a_log_that_is_no_tlog_says_to_replay_it(logs_dir):
    """`gcs status --connect flight.BIN` took the log for a serial port: "cannot open serial port
    flight.BIN: Could not configure port: (25, 'Inappropriate ioctl for device')"."""
    log = logs_dir / "arducopter-sitl-hop.BIN"
    done = subprocess.run(GCS + ["status", "--connect", str(log)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert done.stderr == (
        f"gcs status: {log}: a file, not a serial device: only a .tlog is replayed as a link; "
        f"`gcs replay {log}` replays a .bin, .log or .ulg\n"
    )


def test_status_record_of_a_replayed_tlog_says_why_nothing_is_recorded(logs_dir, tmp_path):
    """--record with a .tlog records nothing (the log is the recording): the report said only
    "recording  off", as if the option had been ignored."""
    done = subprocess.run(
        GCS
        + ["status", "--connect", str(logs_dir / "arduplane-sitl-vtol.tlog"), "--speed", "0", "--duration", "0.5"]
        + ["--record", "--record-dir", str(tmp_path / "sessions")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    assert done.stderr == "gcs status: note: --record: a replayed .tlog is not recorded again (it is the recording)\n"
    assert not (tmp_path / "sessions").exists()
