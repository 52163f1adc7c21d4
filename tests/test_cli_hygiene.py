"""The command line and its sessions, kept clean (issue 12, item 6): SIGTERM closes a session as
Ctrl-C does, .tlog stamps never go backwards, quick looks (`status`, `params`) record only when
asked, a link that never delivered a byte leaves no folder, a failed run never clobbers its
output, a missing serial port fails at once in one line, every --help says what it does, and
numbers are printed without binary noise. Real processes, sockets and files throughout."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from live import running_station, sim_process, stop_process, wait_for

from gcs.batch import dataset
from gcs.commands.cli import build_parser
from gcs.commands.common import tidy
from gcs.logs.readers import READERS
from gcs.mavlink.tlog import read_tlog_records
from gcs.runtime.recorder import RECEIVED, SENT, TlogClock
from gcs.sessions import layout
from gcs.sessions.export import FORMATS
from gcs.sessions.recovery import release_lock, take_lock
from gcs.transport.address import free_port

GCS = [sys.executable, "-m", "gcs"]


def sessions_in(root: Path) -> list[Path]:
    return [p for p in root.iterdir() if layout.is_session(p)] if root.is_dir() else []


def recorded(root: Path, size: int) -> bool:
    """A session under root whose .tlog has `size` bytes."""
    return any((s / layout.TLOG).exists() and (s / layout.TLOG).stat().st_size > size for s in sessions_in(root))


def wait_until(predicate, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, f"timed out after {timeout} s waiting for {what}"
        time.sleep(0.1)


# ---- --help --------------------------------------------------------------------------------
def parsers(parser: argparse.ArgumentParser, name: str = "gcs"):
    """Every parser under `gcs`, with its command line."""
    yield name, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub, p in action.choices.items():
                yield from parsers(p, f"{name} {sub}")


def test_every_help_has_a_description_and_every_option_a_meaning():
    found = dict(parsers(build_parser()))
    assert {"gcs params get", "gcs params diff", "gcs fleet report", "gcs protocol run"} <= set(found)
    for name, parser in found.items():
        assert parser.description and len(parser.description) > 20, name
        for action in parser._actions:
            if not isinstance(action, argparse._SubParsersAction):
                assert action.help and action.help != argparse.SUPPRESS, (name, action.dest)


def test_an_offline_command_imports_neither_the_server_nor_the_references():
    """`gcs replay`, `estimate` and `export` start without the server's web stack, filterpy (the
    kf reference: it imports scipy.stats) or the MATLAB writer: about 2 s of CPU at every start."""
    probe = (
        "import sys\n"
        "from gcs.commands.cli import main\n"
        "for command in ('replay', 'estimate', 'export'):\n"
        "    try:\n"
        "        main([command, '--help'])\n"
        "    except SystemExit:\n"
        "        pass\n"
        "heavy = ('fastapi', 'uvicorn', 'viser', 'filterpy', 'scipy.io', 'gcs.server.app')\n"
        "print('LOADED', [m for m in heavy if m in sys.modules])\n"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120, check=True)
    assert "LOADED []" in out.stdout, out.stdout[-500:]


def test_help_texts_name_what_the_commands_read_and_write():
    found = dict(parsers(build_parser()))
    estimate = found["gcs estimate"].format_help()
    assert all(suffix in estimate for suffix in READERS), estimate  # every input format
    export = found["gcs export"].format_help()
    assert all(fmt in export for fmt in FORMATS) and "attitude" in export and "telemetry" not in export.split(":")[0]
    for action in ("get", "set", "save", "load", "diff"):  # parameters only: no stream or estimator options
        text = found[f"gcs params {action}"].format_help()
        for irrelevant in ("--imu-rate", "--attitude-rate", "--ascii-fields", "--speed", "--no-record"):
            assert irrelevant not in text, (action, irrelevant)
        assert "--record" in text
    assert "--timeout" not in found["gcs params set"].format_help()  # set reads one value, no download


# ---- numbers -------------------------------------------------------------------------------
def test_numbers_are_printed_without_binary_noise():
    f32 = lambda x: float(np.float32(x))  # noqa: E731
    assert tidy(f32(0.1)) == 0.1 and repr(tidy(f32(0.099999994))) == "0.1"
    assert tidy(49.033249999999995) == 49.03325 and tidy(f32(-0.15381026)) == -0.15381026
    assert tidy({"a": [f32(0.2), 3, True, None, "x"]}) == {"a": [0.2, 3, True, None, "x"]}
    assert tidy(1796195034.596995) == 1796195034.597  # a double: 15 significant digits (10 µs here)


# ---- failing fast, failing clean -------------------------------------------------------------
#: A link command's duration far beyond the subprocess's deadline (FAIL_AT_ONCE_S): one that
#: fails at once ends within the deadline; one that listens out its duration is stopped by it.
LISTEN_S, FAIL_AT_ONCE_S = "3600", 120


def test_a_missing_serial_port_fails_at_once_in_one_line():
    done = subprocess.run(
        GCS + ["status", "--connect", "/dev/ttyUSB9", "--duration", LISTEN_S],
        capture_output=True,
        text=True,
        timeout=FAIL_AT_ONCE_S,
    )
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert lines == ["gcs status: error: cannot open serial port /dev/ttyUSB9: No such file or directory"], lines


def test_a_missing_tlog_fails_at_once_in_one_line(tmp_path):
    """A mistyped .tlog to replay as a link is refused as a missing serial port is (found by
    auditing: `gcs status --connect flihgt.tlog` waited out its duration, then printed a report of
    "None"s with no word of the missing file)."""
    missing = tmp_path / "flihgt.tlog"
    done = subprocess.run(
        GCS + ["status", "--connect", str(missing), "--duration", LISTEN_S],
        capture_output=True,
        text=True,
        timeout=FAIL_AT_ONCE_S,
    )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [f"gcs status: error: {missing}: no such file"], done.stderr
    assert done.stdout == ""


def test_a_refused_tcp_connection_is_in_the_status_report(tcp_port):
    """Found by auditing: `gcs status --connect tcp:...` to a SITL that was not running printed
    "waiting, no heartbeat yet" and an empty event list; the refusal the link met and retries was
    left out of every report until a vehicle was heard (the waiting core's view showed only its
    own events)."""
    address = f"tcp:127.0.0.1:{tcp_port}"  # a free port: nothing listens
    done = subprocess.run(
        GCS + ["status", "--connect", address, "--duration", "3"],
        capture_output=True,
        text=True,
        timeout=FAIL_AT_ONCE_S,
    )
    assert done.returncode == 1, done.stderr
    events = done.stdout.split("\nevents\n", 1)[1].splitlines()
    assert f"  transport: cannot open {address}: Connection refused; retrying" in events, done.stdout


LOGS = Path(__file__).resolve().parents[2] / "shared/data/logs"


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["status", "--speed", "-1"], "gcs status: --speed -1.0: give a number >= 0 (0 = as fast as possible)"),
        (["status", "--speed", "nan"], "gcs status: --speed nan: give a number >= 0 (0 = as fast as possible)"),
        (["status", "--imu-rate", "-5"], "gcs status: --imu-rate -5.0: give a rate >= 0 Hz (0 = off)"),
        (["status", "--gps-rate", "inf"], "gcs status: --gps-rate inf: give a rate >= 0 Hz (0 = off)"),
        (["status", "--heartbeat-timeout", "0"], "gcs status: --heartbeat-timeout 0.0: give seconds > 0"),
        (["status", "--duration", "-5"], "gcs status: --duration -5.0: give seconds > 0"),
        (["status", "--duration", "nan"], "gcs status: --duration nan: give seconds > 0"),
        (["demo", "--duration", "-1"], "gcs demo: --duration -1.0: give seconds >= 0 (0: run until Ctrl-C)"),
        (["demo", "--duration", "nan"], "gcs demo: --duration nan: give seconds >= 0 (0: run until Ctrl-C)"),
        (["replay", "--speed", "-1"], "gcs replay: error: --speed -1.0: give a number >= 0 (0 = as fast as possible)"),
        (["replay", "--speed", "nan"], "gcs replay: error: --speed nan: give a number >= 0 (0 = as fast as possible)"),
    ],
)
def test_a_negative_or_not_finite_number_option_is_refused_in_one_line(argv, expected):
    """Found by auditing: `gcs replay --speed -1` (or nan) replayed as fast as possible, a negative
    or NaN --imu-rate asked the vehicle to stop the stream, --heartbeat-timeout 0 called a live
    link lost, `gcs status --duration -5` (or nan) listened for no time and reported "no heartbeat
    yet", `gcs demo --duration -1` (or nan) ran until Ctrl-C; each now ends at once with the option
    and what it takes."""
    hop = str(LOGS / "arducopter-sitl-hop.tlog")
    link = {"status": ["--connect", hop, "--duration", LISTEN_S], "demo": []}.get(argv[0], [hop])
    done = subprocess.run(GCS + [argv[0], *link, *argv[1:]], capture_output=True, text=True, timeout=FAIL_AT_ONCE_S)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [expected], done.stderr


def test_a_failed_estimate_never_clobbers_its_output(tmp_path):
    keep = tmp_path / "keep.csv"
    keep.write_text("the user's earlier results\n")
    empty = tmp_path / "empty.csv"
    empty.write_text("t,gx,gy,gz,ax,ay,az,mx,my,mz\n")  # a valid header, no samples
    for source in (tmp_path / "flihgt.tlog", empty):  # mistyped, then no IMU samples
        done = subprocess.run(
            GCS + ["estimate", str(source), "-e", "dcm", "--out", str(keep)], capture_output=True, text=True, timeout=60
        )
        assert done.returncode == 2 and done.stderr.startswith("gcs estimate: error:"), done.stderr
        assert keep.read_text() == "the user's earlier results\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty.csv", "keep.csv"]  # no temporary left


@pytest.mark.parametrize(
    "command",
    [["estimate", "-e", "dcm"], ["export", "--format", "mat"], ["export", "--format", "mcap"], ["report"]],
)
def test_an_unwritable_output_is_named_as_the_user_gave_it(command, tmp_path):
    """--out under a regular file (or on a read-only file system): the one line names the file
    asked for, not the temporary beside it (found by auditing: the clean-up's unlink failed too,
    with ENOTDIR or EROFS, and its error replaced the first, naming `.o.mat.PID-HEX.tmp`)."""
    (tmp_path / "results").write_text("not a folder\n")
    out = tmp_path / "results" / "o.out"
    hop = str(LOGS / "arducopter-sitl-hop.tlog")
    done = subprocess.run(GCS + [command[0], hop, *command[1:], "--out", str(out)], capture_output=True, text=True)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [f"gcs {command[0]}: error: {out}: Not a directory"], done.stderr


def test_a_fleet_report_of_no_dataset_names_the_dataset(tmp_path):
    """Found by auditing: `gcs fleet report MISSING --out fleet.html` said
    "error: fleet.html: None" (an OSError made from a message alone has no filename or strerror),
    then "no flights in the dataset" for a folder that is not there at all; an empty one has none."""
    missing, page = tmp_path / "fleet", tmp_path / "fleet.html"
    command = GCS + ["fleet", "report", str(missing), "--out", str(page)]
    for expected in ("no such dataset folder (gcs batch --out makes one)", "no flights in the dataset"):
        done = subprocess.run(command, capture_output=True, text=True)
        assert done.returncode == 2 and not page.exists()
        assert done.stderr.strip().splitlines() == [f"gcs fleet report: error: {missing}: {expected}"]
        missing.mkdir(exist_ok=True)  # the second time: a folder with nothing in it


def test_a_sweep_without_held_out_flights_prints_no_nan(tmp_path):
    """Found by auditing: a sweep with no --holdout ended "mean on held-out flights: current nan,
    best nan deg"; the line is left out when no flight was held out."""
    log = str(LOGS / "ardupilot-fragment.bin")
    args = ["sweep", log, "-e", "dcm", "--gain", "kp_rp=0.05:1.0", "--trials", "1", "--workers", "1"]
    done = subprocess.run(GCS + [*args, "--out", str(tmp_path / "fleet")], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "mean on training flights: current " in done.stdout
    assert "held-out" not in done.stdout and "nan" not in done.stdout, done.stdout


def _listener_below_a_free_port() -> tuple[socket.socket, int]:
    """A listening socket on port P - 1 and the free port P above it."""
    while True:
        busy = socket.socket()
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        above = busy.getsockname()[1] + 1
        with socket.socket() as probe:
            try:
                probe.bind(("127.0.0.1", above))
                return busy, above
            except OSError:
                busy.close()


def test_a_taken_3d_view_port_never_takes_the_dashboards(tmp_path):
    """viser moves to the next port when its own is taken; with --viser-port P-1 taken that is the
    dashboard's P, which was bound but not yet listening when viser started: viser took it, the
    printed dashboard URL served viser's page and every /api/ route was 404 (found by auditing
    `gcs serve --port 8701 --viser-port 8700` with 8700 in use)."""
    busy, port = _listener_below_a_free_port()
    taken = port - 1
    serve = GCS + ["serve", "--connect", f"udpin:127.0.0.1:{free_port(socket.SOCK_DGRAM)}", "--no-record"]
    proc = subprocess.Popen(
        serve + ["--port", str(port), "--viser-port", str(taken)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT
    )
    try:
        deadline, answer = time.monotonic() + 60, None
        while answer is None or answer.status_code != 200:
            assert time.monotonic() < deadline, f"no dashboard on {port}: {answer and answer.status_code}"
            assert proc.poll() is None, proc.stdout.read().decode() if proc.stdout else ""
            with contextlib.suppress(httpx.TransportError):
                answer = httpx.get(f"http://127.0.0.1:{port}/api/status", timeout=5)
            time.sleep(0.2)
        assert answer.json()["viser_port"] not in (port, taken)
    finally:
        stop_process(proc)
        busy.close()


@pytest.mark.parametrize("command", ["demo", "serve"])
def test_a_taken_dashboard_port_is_one_line_naming_it(command):
    """Found by auditing `gcs demo --port 8700` with 8700 in use: a traceback ending in
    "OSError: [Errno 98] Address already in use" (`gcs serve` said that line alone, no port)."""
    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen()
    port = busy.getsockname()[1]
    link = ["--connect", f"udpin:127.0.0.1:{free_port(socket.SOCK_DGRAM)}"] if command == "serve" else []
    try:
        done = subprocess.run(
            GCS + [command, *link, "--no-record", "--port", str(port)], capture_output=True, text=True, timeout=60
        )
    finally:
        busy.close()
    assert done.returncode == 2, done.stderr
    expected = f"gcs {command}: error: cannot serve the dashboard on 127.0.0.1:{port} (--port): Address already in use"
    assert done.stderr.strip().splitlines() == [expected], done.stderr


# ---- recording only when asked, and only what arrived -------------------------------------------
def test_status_records_only_with_record_and_never_for_a_silent_link(tmp_path):
    quiet = tmp_path / "quiet"
    done = subprocess.run(
        GCS
        + ["status", "--connect", f"udpin:127.0.0.1:{free_port()}", "--duration", "1"]
        + ["--record", "--record-dir", str(quiet)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 1  # no heartbeat
    assert sessions_in(quiet) == []  # asked to record, but nothing ever arrived: no folder

    port = free_port()
    sim = subprocess.Popen(
        GCS + ["sim", "--profile", "apm25", "--link", f"udpout:127.0.0.1:{port}"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        for extra, root in (([], tmp_path / "plain"), (["--record"], tmp_path / "asked")):
            done = subprocess.run(
                GCS
                + ["status", "--connect", f"udpin:127.0.0.1:{port}", "--duration", "4"]
                + [*extra, "--record-dir", str(root)],
                capture_output=True,
                text=True,
                timeout=60,
                cwd=tmp_path,
            )
            assert done.returncode == 0, done.stderr
    finally:
        sim.terminate()
        sim.wait(10)
    assert not (tmp_path / "plain").exists() and not (tmp_path / "sessions").exists()
    [session] = sessions_in(tmp_path / "asked")
    assert (session / layout.TLOG).stat().st_size > 0


def test_status_of_a_silent_link_says_nothing_was_heard_without_nones():
    """Found by auditing `gcs status` on a link nobody sends to: its report read "heartbeat age
    None s", "sysid None  None  None  MAVLink None" and "via None"."""
    address = f"udpin:127.0.0.1:{free_port()}"
    done = subprocess.run(
        GCS + ["status", "--connect", address, "--duration", "1"], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 1  # no heartbeat
    lines = done.stdout.splitlines()
    assert "None" not in done.stdout, done.stdout
    assert lines[0] == f"link       {address}  state waiting  no heartbeat yet", lines
    assert lines[1] == "vehicle    none heard", lines
    assert lines[3] == "streams    none requested yet", lines


# ---- SIGTERM is Ctrl-C ----------------------------------------------------------------------
def test_sigterm_closes_the_session_as_ctrl_c_does(tmp_path):
    port = free_port()
    sim = subprocess.Popen(
        GCS + ["sim", "--profile", "pixhawk", "--script", "quad", "--link", f"udpout:127.0.0.1:{port}"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    commands = {
        "serve": ["serve", "--port", str(free_port(__import__("socket").SOCK_STREAM))],
        "status": ["status", "--duration", "600", "--record"],
    }
    try:
        for name, command in commands.items():
            root = tmp_path / name
            proc = subprocess.Popen(
                GCS + [*command, "--connect", f"udpin:127.0.0.1:{port}", "--record-dir", str(root)],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
                text=True,
            )
            try:
                wait_until(lambda root=root: recorded(root, 20_000), 90, f"gcs {name} recording")
                proc.send_signal(signal.SIGTERM)
                rc = proc.wait(60)
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
            assert rc == 143, (name, rc, proc.stderr.read() if proc.stderr else "")
            [info] = layout.list_sessions(root)
            assert not info.open and info.end is not None and info.duration_s > 0, (name, info)
            session = Path(info.path)
            meta = json.loads((session / layout.META).read_text())
            assert meta["end"] is not None
            assert any(session.glob("*.parquet")), sorted(p.name for p in session.iterdir())
            release_lock(take_lock(session))  # no process holds it any more (take_lock raises if one does)
    finally:
        sim.terminate()
        sim.wait(10)


def test_sigterm_stops_a_command_started_with_sigint_ignored():
    """A background job of a script (`gcs sim &`) starts with SIGINT ignored: SIGTERM still stops
    it (it had become an ignored SIGINT, and the process ran on until killed)."""
    sim = subprocess.Popen(
        GCS + ["sim", "--profile", "apm25", "--link", f"udpout:127.0.0.1:{free_port()}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )
    try:
        assert "apm25" in sim.stdout.readline()  # printed once its link is open
        sim.send_signal(signal.SIGTERM)
        rc = sim.wait(60)  # a deadline for a hang only
    finally:
        if sim.poll() is None:
            sim.kill()
            sim.wait()
    assert rc == 0, (rc, sim.stderr.read())  # `gcs sim` ends cleanly when stopped, as on Ctrl-C


# ---- .tlog stamps ---------------------------------------------------------------------------------
def test_tlog_stamps_never_go_backwards_with_sent_and_received_packets(udp_port, tmp_path):
    async def scenario() -> Path:
        async with (
            running_station(f"udpin:127.0.0.1:{udp_port}", sessions_dir=str(tmp_path), record=True) as station,
            sim_process(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk", script="quad"),
        ):
            await wait_for(lambda: station.recorder.packets["sent"] >= 8, 90, "packets sent to the vehicle")
            await wait_for(lambda: station.recorder.packets["received"] > 2000, 90, "packets received")
            station.params.request(["COMPASS_DEC", "SYSID_THISMAV"])  # more sends amid the stream
            await asyncio.sleep(0)
            await wait_for(lambda: station.recorder.packets["sent"] >= 10, 60, "the parameter requests")
            folder = station.recorder.session.folder
        return folder

    folder = asyncio.run(scenario())
    stamps = [usec for usec, _ in read_tlog_records(folder / layout.TLOG)]
    sent = [k for k, usec in enumerate(stamps) if usec & 3 == SENT]
    assert len(sent) >= 10 and len(stamps) > 2000
    received = [k for k, usec in enumerate(stamps) if usec & 3 != SENT]
    assert any(received[0] < k < received[-1] for k in sent)  # sends between received packets, not only at an end
    # the whole stamp, link bits included: pymavlink, MAVProxy and Mission Planner read it as the time
    backwards = [(k, stamps[k - 1] - stamps[k]) for k in range(1, len(stamps)) if stamps[k] < stamps[k - 1]]
    assert backwards == [], backwards[:5]


def test_a_packet_received_before_a_send_is_stamped_after_it_link_bits_and_all():
    """A chunk read before a send but stamped after it takes the send's µs: with the link bits
    (3 on the sent packet, 0 on the received) that stamp was 3 µs earlier than the send's."""
    clock = TlogClock()
    sent = clock.stamp(1.7e9 + 0.000101, SENT)
    received = clock.stamp(1.7e9 + 0.000050, RECEIVED)
    assert sent & 3 == SENT and received & 3 == RECEIVED
    assert received > sent and received - sent <= 4


@pytest.mark.parametrize(
    ("command", "written"),
    [
        (["report", "--out", "r.html"], ["r.html"]),
        (["export", "--format", "mat", "--out", "x.mat"], ["x.mat"]),
        (["export", "--format", "mcap", "--out", "x.mcap"], ["x.mcap"]),
        (["batch", "--out", "fleet", "-e", "dcm", "--workers", "1"], ["fleet/flights"]),
    ],
)
def test_a_log_whose_name_is_not_utf8_is_read_and_written_about(command, written, tmp_path):
    """A name made elsewhere (a Latin-1 machine, a FAT stick): Python keeps its byte 0xE9 as a lone
    surrogate, which the report's page, the .mat's info, the MCAP's metadata, Dask's task key and
    Parquet all refused in a traceback (found by auditing). The name is written with U+FFFD there."""
    log = tmp_path / os.fsdecode(b"vol-caf\xe9.bin")
    log.write_bytes((LOGS / "ardupilot-fragment.bin").read_bytes())
    done = subprocess.run(
        GCS + [command[0], str(log), *command[1:]], capture_output=True, text=True, cwd=tmp_path, timeout=300
    )
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    assert all((tmp_path / name).exists() for name in written)
    if command[0] == "report":
        assert "vol-caf\ufffd.bin" in (tmp_path / "r.html").read_text(encoding="utf-8")


def _session_of_the_hop(folder: Path) -> Path:
    """A session folder made of the hop's tlog: its telemetry, a meta.json and an events.jsonl
    with a note (the attitude tables absent: export and report replay the tlog)."""
    folder.mkdir()
    (folder / layout.TLOG).write_bytes((LOGS / "arducopter-sitl-hop.tlog").read_bytes())
    (folder / layout.META).write_text(json.dumps({"start": 1.7e9, "end": 1.7e9 + 88, "vehicle": {"label": "hop"}}))
    (folder / layout.EVENTS).write_text('{"kind": "note", "text": "gusty", "wall_time": 1700000010.0}\n')
    return folder


@pytest.mark.parametrize(
    "command",
    [["replay", "--fast"], ["report", "--out", "r.html"], ["export", "--format", "mat", "--out", "x.mat"]],
)
def test_a_flipped_byte_in_events_jsonl_costs_its_line_only(command, tmp_path):
    """read_events skips a damaged line, but a byte that is not UTF-8 (0xE9 for the note's "s")
    made the whole file unreadable: a UnicodeDecodeError traceback from report and the .mat and
    .mcap exports, and from replay one line naming no file (found by the audit)."""
    session = _session_of_the_hop(tmp_path / "session")
    events = session / layout.EVENTS
    events.write_bytes(events.read_bytes().replace(b"gusty", b"gu\xe9ty") + b'{"kind": "note", "te\xff\n')
    done = subprocess.run(
        GCS + [command[0], str(session), *command[1:]], capture_output=True, text=True, cwd=tmp_path, timeout=300
    )
    assert done.returncode == 0 and "Traceback" not in done.stderr and "error:" not in done.stderr, done.stderr
    if command[0] == "report":
        assert "gu\ufffdty" in (tmp_path / "r.html").read_text(encoding="utf-8")  # the note, its byte marked


def test_a_session_file_that_cannot_be_read_is_one_line_from_replay(tmp_path):
    """A folder where events.jsonl should be (any OSError reading the session) was a traceback
    from gcs replay (found by the audit), where report and export said it in one line."""
    session = _session_of_the_hop(tmp_path / "session")
    (session / layout.EVENTS).unlink()
    (session / layout.EVENTS).mkdir()
    done = subprocess.run(GCS + ["replay", str(session), "--fast"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [f"gcs replay: error: {session / layout.EVENTS}: Is a directory"]


@pytest.mark.parametrize(
    "argv",
    [
        ["batch", "--workers", "-1"],
        ["batch", "--workers", "0"],
        ["sweep", "-e", "dcm", "--gain", "kp_rp=0.1:0.5", "--workers", "-1"],
    ],
)
def test_a_batch_or_sweep_on_no_local_workers_is_refused_at_once(argv, tmp_path):
    """Found by the audit: `gcs batch LOGS --out D --workers -1` started a LocalCluster with no
    worker and waited for its tasks forever, without a word (`--workers 0` quietly meant the default)."""
    out = tmp_path / "fleet"
    command = GCS + [argv[0], str(LOGS / "ardupilot-fragment.bin"), *argv[1:], "--out", str(out)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=FAIL_AT_ONCE_S)
    assert done.returncode == 2 and not out.exists()
    workers = argv[-1]
    expected = f"gcs {argv[0]}: error: --workers {workers}: give 1 or more local workers (default: cores, at most 4)"
    assert done.stderr.strip().splitlines() == [expected], done.stderr


def test_a_fleet_report_skips_a_flight_whose_file_is_damaged_and_reports_the_rest(tmp_path):
    """A dataset copied off a full card or cut in an interrupted copy: one flight's summary.parquet
    cut, overwritten with flipped bytes or not Parquet at all, or a failure's file overwritten,
    failed `gcs fleet report` whole (exit 2, no page) for the fleet. That flight is skipped with
    one line naming its file, the page holds the others and lists it, and the exit status is 1."""
    logs = tmp_path / "logs"
    logs.mkdir()
    for name in ("a.bin", "b.bin"):
        (logs / name).write_bytes((LOGS / "ardupilot-fragment.bin").read_bytes())
    (logs / "junk.tlog").write_bytes(b"not a log")
    fleet = tmp_path / "fleet"
    built = subprocess.run(
        GCS + ["batch", str(logs), "--out", str(fleet), "-e", "dcm", "--workers", "1"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert built.returncode == 0, built.stderr
    summary = fleet / "flights" / f"flight={dataset.flight_id(logs / 'a.bin')}" / "summary.parquet"
    (failure,) = fleet.glob("failures/*.parquet")
    data = summary.read_bytes()
    flipped = bytes(b ^ 0x55 if 50 < k < len(data) - 50 else b for k, b in enumerate(data))
    for damaged, content, flights in (
        (summary, b"", 1),
        (summary, data[: len(data) // 2], 1),
        (summary, flipped, 1),
        (summary, b"junk\n" * 100, 1),
        (failure, b"junk\n", 2),
    ):
        kept = damaged.read_bytes()
        damaged.write_bytes(content)
        page = tmp_path / "fleet.html"
        done = subprocess.run(
            GCS + ["fleet", "report", str(fleet), "--out", str(page)], capture_output=True, text=True, timeout=300
        )
        damaged.write_bytes(kept)
        assert done.returncode == 1, done.stderr
        skipped, wrote = done.stderr.strip().splitlines()
        flight = damaged.parent.name if damaged is summary else damaged.stem
        assert skipped.startswith(f"skipped {flight.removeprefix('flight=')}: {damaged}: "), skipped
        assert wrote == f"wrote {page} ({flights} flights, 1 skipped)"
        text = page.read_text()
        assert "<h2>Skipped: a file of theirs in the dataset cannot be read</h2>" in text
        assert dataset.flight_id(logs / "b.bin") in text
        page.unlink()
    done = subprocess.run(GCS + ["fleet", "report", str(fleet), "--out", str(page)], capture_output=True, text=True)
    assert done.returncode == 0 and done.stderr.strip() == f"wrote {page} (2 flights, 0 skipped)", done.stderr


def test_an_estimate_whose_out_is_its_input_is_refused(tmp_path):
    """`gcs estimate flight.csv -e dcm --out flight.csv` (a CSV in, a CSV out) replaced the
    engineer's IMU samples with the estimates made from them, exit 0 (found by the audit)."""
    samples = tmp_path / "flight.csv"
    text = "t,gx,gy,gz,ax,ay,az,mx,my,mz\n" + "".join(f"{k / 100},0,0,0,0,0,-9.8,0.2,0,0.4\n" for k in range(50))
    samples.write_text(text)
    done = subprocess.run(
        GCS + ["estimate", "flight.csv", "-e", "dcm", "--out", "flight.csv"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=60,
    )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "gcs estimate: error: --out flight.csv is INPUT itself; give another file"
    ]
    assert samples.read_text() == text and [p.name for p in tmp_path.iterdir()] == ["flight.csv"]


def test_a_listing_piped_into_a_reader_that_stops_ends_quietly(tmp_path):
    """`gcs sessions --json | head -1`: the reader gone, the command stops as a C tool killed by
    SIGPIPE does (exit 141), without a BrokenPipeError traceback."""
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone before the command writes
    try:
        done = subprocess.run(
            [*GCS, "sessions", "--json", "--dir", str(tmp_path)],
            stdout=write_end, stderr=subprocess.PIPE, text=True, timeout=60,
        )  # fmt: skip
    finally:
        os.close(write_end)
    assert (done.returncode, done.stderr) == (128 + signal.SIGPIPE, "")


def test_a_dashboard_on_every_interface_prints_the_urls_other_machines_open():
    """`gcs serve --host 0.0.0.0` printed http://0.0.0.0:PORT, which no teammate's laptop can open
    (found by the audit): it prints this machine's URL, then one per interface address, and each
    of those serves the page."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.connect(("192.0.2.1", 9))  # nothing is sent: the kernel picks the interface it would leave by
        outgoing = probe.getsockname()[0]
    port = free_port()
    link = f"udpin:127.0.0.1:{free_port(socket.SOCK_DGRAM)}"
    argv = ["serve", "--connect", link, "--no-record", "--host", "0.0.0.0", "--port", str(port), "--token", "t0k"]
    proc = subprocess.Popen(GCS + argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert proc.stdout is not None
        lines: list[str] = []
        while not lines or "from other machines" not in lines[-1]:
            line = proc.stdout.readline()
            assert line, f"gcs serve ended: {lines}"
            lines.append(line)
        assert f"dashboard at http://127.0.0.1:{port}/?token=t0k " in "".join(lines)
        shared = lines[-1].split("from other machines: ", 1)[1].split()
        assert f"http://{outgoing}:{port}/?token=t0k" in shared
        for url in shared:
            page = httpx.get(url, timeout=10, follow_redirects=True)
            assert page.status_code == 200 and "uPlot.iife.min.js" in page.text, url
    finally:
        stop_process(proc)


@pytest.mark.parametrize(
    ("command", "recorded"),
    [
        (["export", "--format", "parquet", "--out"], "attitude.parquet"),
        (["report", "--out"], layout.EVENTS),
        (["export", "--format", "csv", "--out"], layout.TLOG),
    ],
)
def test_an_output_never_replaces_a_file_its_session_recorded(command, recorded, tmp_path):
    """`gcs export S --format parquet --out S/attitude.parquet` replaced the session's own table,
    exit 0 (found by the audit): the output is refused in one line and the file kept."""
    session = _session_of_the_hop(tmp_path / "session")
    kept = session / recorded
    before = kept.read_bytes() if kept.exists() else None  # a table it has not written yet is its too
    done = subprocess.run(
        GCS + [command[0], str(session), *command[1:], str(session / recorded)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode != 0 and (kept.read_bytes() if kept.exists() else None) == before
    (line,) = done.stderr.strip().splitlines()
    assert str(session / recorded) in line and "session recorded" in line, line


def test_sessions_of_a_folder_that_is_not_there_says_so(tmp_path):
    """`gcs sessions --dir MISTYPED` said "no sessions in MISTYPED", exit 0, as for a folder with
    none (found by the audit); the default ./sessions, not made until a first recording, still
    reads as no sessions."""
    done = subprocess.run(GCS + ["sessions", "--dir", str(tmp_path / "sesions")], capture_output=True, text=True)
    assert (done.returncode, done.stderr) == (2, f"gcs sessions: error: {tmp_path / 'sesions'}: no such folder\n")
    fresh = subprocess.run(GCS + ["sessions"], capture_output=True, text=True, cwd=tmp_path)
    assert (fresh.returncode, fresh.stderr) == (0, "no sessions in sessions\n")


def test_a_fleet_report_of_a_negative_number_of_worst_flights_is_refused(tmp_path):
    """`gcs fleet report D --worst -2` was taken silently as none (found by the audit)."""
    out = tmp_path / "fleet.html"
    argv = ["fleet", "report", str(tmp_path), "--out", str(out), "--worst", "-2"]
    done = subprocess.run(GCS + argv, capture_output=True, text=True, timeout=FAIL_AT_ONCE_S)
    assert done.returncode == 2 and not out.exists()
    expected = "gcs fleet report: error: argument --worst: -2: give 0 or more flights"
    assert done.stderr.strip().splitlines()[-1] == expected
