"""gcs batch, sweep and fleet report on a real Dask scheduler with two real workers on loopback,
over the shared recordings, short simulator sessions, a truncated and an unreadable file."""

from __future__ import annotations

import contextlib
import io
import math
import os
import resource
import select
import shutil
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import pyarrow.parquet as pq
import pytest
from distributed import Client
from fastapi.testclient import TestClient

from gcs.batch import dataset
from gcs.batch.sweep import FlightOutcome, SweepResult, write_sweep
from gcs.commands.cli import build_parser, main
from gcs.commands.serve import presets_or_report
from gcs.core.estimators import registry
from gcs.core.gains import PresetFile
from gcs.mavlink.sampling import IMU_TYPES
from gcs.runtime.replay import ReplaySession
from gcs.runtime.station import Station, StationConfig
from gcs.server.app import create_app
from gcs.sessions import layout
from gcs.sessions.sources import open_source
from gcs.sim.recording import write_tlog
from gcs.transport.address import free_port

DASK = str(Path(sys.executable).with_name("dask"))
#: A deliberately bad recorded DCM gain: the sweep must find better on flights it did not see.
BAD_KP_RP = 0.005
SIM_SECONDS = 15


@dataclass(frozen=True)
class Ran:
    stdout: str
    stderr: str


def _cli(*args: str) -> Ran:
    """`gcs ARGS` in this process (the command line's own entry point; a process start less per
    call), which must succeed."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(args))
    assert code == 0, err.getvalue()[-3000:]
    return Ran(out.getvalue(), err.getvalue())


@pytest.fixture(scope="module")
def scheduler():
    """`dask scheduler` and two `dask worker` processes on 127.0.0.1, ready (or the test fails)."""
    port = free_port(socket.SOCK_STREAM)
    address = f"tcp://127.0.0.1:{port}"
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    procs = [
        subprocess.Popen([DASK, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"], **quiet)
    ]
    for _ in range(2):
        procs.append(
            subprocess.Popen(
                [DASK, "worker", address, "--nthreads", "1", "--host", "127.0.0.1", "--no-dashboard"], **quiet
            )
        )
    try:
        deadline = time.monotonic() + 120
        with Client(address, timeout="120s") as client:
            client.wait_for_workers(2, timeout=max(1.0, deadline - time.monotonic()))
        yield address
    finally:
        for proc in reversed(procs):
            proc.terminate()
        for proc in procs:
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


@pytest.fixture(scope="module")
def flights(tmp_path_factory, logs_dir) -> dict[str, list[str]]:
    """good: the shared logs, 4 simulator sessions (recorded with a bad kp_rp, two vehicles) and a
    truncated copy of the hop; bad: a file with no log in it."""
    root = tmp_path_factory.mktemp("fleet")
    sessions = []
    for seed in range(1, 5):
        folder = root / f"sim-{seed}"
        folder.mkdir()
        write_tlog(folder / layout.TLOG, SIM_SECONDS, seed=seed)
        layout.write_meta(
            folder,
            {
                "start": 1_700_000_000.0 + 86400 * seed,
                "vehicle": {"label": f"sim-quad-{'ab'[seed % 2]}", "firmware": "sim"},
                "estimation": {"estimators": {"dcm": {"preset": "ardupilot", "gains": {"kp_rp": BAD_KP_RP}}}},
            },
        )
        sessions.append(str(folder))
    cut = root / "hop-cut.tlog"
    data = (logs_dir / "arducopter-sitl-hop.tlog").read_bytes()
    cut.write_bytes(data[: len(data) // 3 + 7])  # mid-record
    junk = root / "junk.bin"
    junk.write_bytes(b"\x00not a log\xff" * 50)
    shared = sorted(str(p) for p in logs_dir.iterdir() if p.suffix.lower() in (".tlog", ".bin", ".ulg"))
    return {"good": [*shared, *sessions, str(cut)], "bad": [str(junk)], "sessions": sessions}


@pytest.fixture(scope="module")
def batch(tmp_path_factory, flights, scheduler) -> Path:
    out = tmp_path_factory.mktemp("ds") / "fleet"
    _cli("batch", *flights["good"], *flights["bad"], "--out", str(out), "-e", "dcm", "--scheduler", scheduler)
    return out


def _by_key(table) -> dict:
    return {(r["flight"], r["estimator"], r["reference"]): r for r in table.to_pylist()}


def test_every_good_flight_is_in_the_dataset_and_the_bad_one_is_a_failure_row(batch, flights):
    assert dataset.done_flights(batch) == {dataset.flight_id(p) for p in flights["good"]}
    assert len(flights["good"]) + len(flights["bad"]) >= 8
    failures = dataset.read_failures(batch).table.to_pylist()
    assert [f["flight"] for f in failures] == [dataset.flight_id(flights["bad"][0])]
    assert "junk.bin" in failures[0]["reason"]
    summary = dataset.read_table(batch, "summary").to_pylist()
    cut = dataset.flight_id(flights["good"][-1])
    assert all("last record incomplete" in r["damage"] for r in summary if r["flight"] == cut)
    sim = [r for r in summary if r["path"] in flights["sessions"]]
    assert {r["vehicle"] for r in sim} == {"sim-quad-a", "sim-quad-b"}
    # a bare tlog's vehicle is named from its HEARTBEAT, as a session's is (it was "unknown")
    named = {Path(r["path"]).name: r["vehicle"] for r in summary if r["path"].endswith(".tlog")}
    assert named["arducopter-sitl-hop.tlog"] == named["hop-cut.tlog"] == "ArduPilot-QUADROTOR-1", named
    assert named["arduplane-sitl-vtol.tlog"] == "ArduPilot-FIXED_WING-1", named
    # a DataFlash or ULog flight's from what the log says (it was "unknown"): the hop's banner
    # "ArduCopter V4.7.0-dev", FRAME_CLASS 1 and MAV_SYSID 1 (as its tlog's HEARTBEAT); the
    # fragment's "ArduPlane V3.8.2-dev", Q_ENABLE 0, SYSID_THISMAV 1; the ULog's sys_name "PX4",
    # MAV_TYPE 2, MAV_SYS_ID 1
    logs = {Path(r["path"]).name: r["vehicle"] for r in summary if r["path"].endswith((".BIN", ".bin", ".ulg"))}
    assert logs == {
        "arducopter-sitl-hop.BIN": "ArduPilot-QUADROTOR-1",
        "ardupilot-fragment.bin": "ArduPilot-FIXED_WING-1",
        "px4-flight-sample.ulg": "PX4-QUADROTOR-1",
    }, logs
    # and its firmware from what the log says (it was empty for every bare log): a DataFlash MSG
    # banner, a tlog's STATUSTEXT banner, a ULog's ver_sw git hash (it has no ver_sw_release); the
    # hop's tlog has no banner and no AUTOPILOT_VERSION, and says none
    firmware = {Path(r["path"]).name: r["firmware"] for r in summary if r["path"] not in flights["sessions"]}
    assert firmware["arducopter-sitl-hop.BIN"] == "ArduCopter 4.7.0-dev (90700977)", firmware
    assert firmware["ardupilot-fragment.bin"] == "ArduPlane 3.8.2-dev (8178ab40)", firmware
    assert firmware["arduplane-sitl-vtol.tlog"] == "ArduPlane 3.10.0-dev (f2b4e06a)", firmware
    assert firmware["px4-flight-sample.ulg"] == "git fd483321", firmware
    assert firmware["arducopter-sitl-hop.tlog"] == "", firmware
    # onboard-unready: ATTITUDE sent while the vehicle's EKF said it was not ready (its boot)
    assert all(r["reference"] in ("onboard", "onboard-unready", "ahrs2", "truth") and r["n"] > 0 for r in summary)
    unready = {Path(r["path"]).name for r in summary if r["reference"] == "onboard-unready"}
    assert unready and all(name.endswith(".tlog") for name in unready), unready  # EKF_STATUS_REPORT
    attitude = dataset.read_table(batch, "attitude")
    assert set(attitude["flight"].unique().to_pylist()) == dataset.done_flights(batch)


SHARED_LOGS = [
    "arducopter-sitl-hop.tlog",
    "arducopter-sitl-hop.BIN",
    "ardupilot-fragment.bin",
    "arduplane-sitl-vtol.tlog",
    "px4-flight-sample.ulg",
]


@pytest.mark.parametrize("which", [*SHARED_LOGS, "sim-1", "hop-cut.tlog"])  # every reader, every shared log
def test_per_flight_figures_equal_gcs_replay(batch, flights, which):
    path = next(p for p in flights["good"] if Path(p).name == which)
    session = ReplaySession(open_source(path), 0, ["dcm"])
    session.run_to_end()
    summary = session.pipeline.comparisons["dcm"].summary()
    rows = {
        r["reference"]: r
        for r in pq.read_table(dataset.flight_dir(batch, dataset.flight_id(path)) / "summary.parquet").to_pylist()
    }
    assert set(rows) == set(summary["references"])
    for ref, stats in summary["references"].items():
        s = stats["session"]
        assert rows[ref]["n"] == s["n"]
        assert [rows[ref][f"rms_{a}"] for a in ("roll", "pitch", "yaw")] == s["rms"]
        assert [rows[ref][f"max_{a}"] for a in ("roll", "pitch", "yaw")] == s["max"]
        assert rows[ref]["lag_s"] == summary["lag"]
    assert rows[next(iter(rows))]["imu_samples"] == session.pipeline.imu_samples


def test_local_cluster_gives_the_same_dataset(batch, flights, tmp_path):
    out = tmp_path / "local"
    _cli("batch", *flights["good"], *flights["bad"], "--out", str(out), "-e", "dcm", "--workers", "2")
    for table in ("summary", "comparison"):
        ours, theirs = _by_key(dataset.read_table(out, table)), _by_key(dataset.read_table(batch, table))
        assert ours.keys() == theirs.keys()
        for key in ours:
            for col, value in ours[key].items():
                same = value == theirs[key][col] or (
                    isinstance(value, float) and math.isnan(value) and math.isnan(theirs[key][col])
                )
                assert same, (key, col, value, theirs[key][col])
    one = dataset.flight_id(flights["sessions"][0])
    ours, theirs = (pq.read_table(dataset.flight_dir(d, one) / "attitude.parquet") for d in (out, batch))
    assert ours.num_rows > 1000 and ours.drop_columns(["wall_time"]).equals(theirs.drop_columns(["wall_time"]))
    assert dataset.read_failures(out).table.to_pylist() == dataset.read_failures(batch).table.to_pylist()


#: A batch writer in its own process: it holds its partition's temporary folder as write_flight
#: does (or, given "file", a failure's temporary file as write_failure does), says so, and goes on
#: writing until it is killed.
WRITER = """
import sys, time
from pathlib import Path
from gcs.batch.dataset import writing
path, folder = Path(sys.argv[1]), sys.argv[2] == "folder"
with writing(path, folder):
    (path / "attitude.parquet" if folder else path).write_bytes(b"half a partition")
    print("writing", flush=True)
    time.sleep(600)
"""


def _writer(path: Path, kind: str = "folder") -> subprocess.Popen:
    """A real process writing `path` (a "folder" or a "file"), once it holds it (or the test fails)."""
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path), kind], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], 120)
    assert ready and proc.stdout.readline() == "writing\n", f"the writer of {path} did not start"
    return proc


#: A batch writing one flight over and over in its own process (as two `gcs batch --force` into
#: one dataset write the flights they share), printing how many of its writes raised and why.
REWRITER = """
import sys
from pathlib import Path
import pyarrow as pa
from gcs.batch.dataset import write_flight
tables = {name: pa.table({"x": [1, 2, 3]}) for name in ("attitude", "summary")}
errors = []
for _ in range(int(sys.argv[2])):
    try:
        write_flight(Path(sys.argv[1]), "shared-1234abcd", tables)
    except OSError as exc:
        errors.append(repr(exc))
print(len(errors), errors[:1])
"""


def test_two_runs_writing_one_flight_at_once_each_write_it_whole(tmp_path):
    """Found by the audit: the partition was moved aside and the new one renamed in as two steps,
    so a run between them found it gone (FileNotFoundError) or back in place (ENOTEMPTY), and
    recorded a flight that was in the dataset as failed: 1 to 17 of 600 writes each, every try."""
    runs = [
        subprocess.Popen([sys.executable, "-c", REWRITER, str(tmp_path), "500"], stdout=subprocess.PIPE, text=True)
        for _ in range(2)
    ]
    printed = [run.communicate(timeout=300)[0].strip() for run in runs]
    assert printed == ["0 []", "0 []"]
    flight = dataset.flight_dir(tmp_path, "shared-1234abcd")
    assert sorted(p.name for p in flight.iterdir()) == ["attitude.parquet", "summary.parquet"]
    assert [p.name for p in flight.parent.iterdir()] == [flight.name]  # no temporary left


def test_two_sweeps_started_in_one_second_each_keep_their_result(tmp_path):
    """A sweep's folder is named after its start second: of two sweeps of one estimator started
    together (a script tuning two gain sets at once), the one finishing second failed on
    "Directory not empty" and lost its result (found by the audit). It is written as `-2`."""
    folder = tmp_path / dataset.SWEEPS / "dcm-20261206-033840"
    flight = FlightOutcome("a.bin", "ArduPilot-QUADROTOR-1", False, 1.5, 1.2)
    runner = SimpleNamespace(ranges=[SimpleNamespace(name="kp_rp")], gain_sets=[{"kp_rp": 0.3}], scores=[[1.2]])
    written = []
    for best in (0.3, 0.4):
        result = SweepResult("dcm", "rms_vs_onboard", {"kp_rp": best}, 1.2, {}, [flight], 1, folder)
        written.append(write_sweep(result, runner))  # a stand-in with the Trials fields it reads
    assert written == [folder, folder.with_name(f"{folder.name}-2")]
    for path, best in zip(written, (0.3, 0.4), strict=True):
        assert PresetFile.from_toml((path / "preset.toml").read_text(), str(path)).gains == {"kp_rp": best}
        assert pq.read_table(path / "flights.parquet").num_rows == 1


def _files_up_to_1_kib() -> None:
    resource.setrlimit(resource.RLIMIT_FSIZE, (1024, 1024))  # EFBIG past it, as ENOSPC on a full disk


def test_a_dataset_that_cannot_be_written_is_one_line_naming_it(tmp_path, logs_dir):
    """A dataset on a full disk (a file size limit here, the workers' too): a flight's partition
    cannot be written, nor then its failure row, and the task raised. Dask's worker logged its
    "Compute Failed" and traceback, and the command said "lost the Dask scheduler" (found by the
    audit): the task's OSError was taken for the cluster's. One line names the dataset now."""
    out = tmp_path / "fleet"
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "gcs",
            "batch",
            str(logs_dir / "ardupilot-fragment.bin"),
            "--out",
            str(out),
            "-e",
            "dcm",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        preexec_fn=_files_up_to_1_kib,
    )
    assert done.returncode == 2
    (line,) = done.stderr.strip().splitlines()
    assert line.startswith(f"gcs batch: error: {out}: ") and "File too large" in line, line


def test_a_failures_file_is_no_executable(tmp_path):
    """A failure's Parquet file was made by os.open with its default mode 0o777: rwxr-xr-x under
    the usual umask, an executable data file (found by the audit). It is made as open() makes one."""
    dataset.write_failure(tmp_path, "junk.tlog-1234abcd", "junk.tlog", "junk.tlog: offset 0: not a log")
    (failure,) = (tmp_path / dataset.FAILURES).iterdir()
    assert failure.stat().st_mode & 0o111 == 0, oct(failure.stat().st_mode)
    assert dataset.read_failures(tmp_path).table.to_pylist()[0]["reason"] == "junk.tlog: offset 0: not a log"


def test_next_batch_removes_what_a_killed_writer_left_never_a_live_ones(flights, scheduler, tmp_path):
    """A writer killed with SIGKILL mid-flight (as a killed worker or scheduler leaves it) left its
    temporary folder and the partition it was replacing: the next batch removes both and says so
    in one line. Another run's writer, alive, keeps its folder and the partition it moved aside."""
    out = tmp_path / "fleet"
    target = dataset.flight_dir(out, "telemetry.tlog-0badc0de")
    target.parent.mkdir(parents=True)
    dead, alive = ("4242-deadbeef", "4343-a11ca7ed")
    killed = _writer(dataset.scratch(target, dead, dataset.WRITING))
    dataset.scratch(target, dead, dataset.REPLACED).mkdir()
    live = _writer(dataset.scratch(target, alive, dataset.WRITING))
    dataset.scratch(target, alive, dataset.REPLACED).mkdir()
    try:
        killed.kill()
        killed.wait(timeout=60)
        session = flights["sessions"][0]
        ran = _cli("batch", session, "--out", str(out), "-e", "dcm", "--scheduler", scheduler)
        gone = [dataset.scratch(target, dead, kind).name for kind in (dataset.WRITING, dataset.REPLACED)]
        assert (
            f"removed 2 temporary files and folders a killed run left in {out}: {', '.join(sorted(gone))}\n"
            in ran.stdout
        )
        assert sorted(p.name for p in target.parent.iterdir() if p.name.startswith(".")) == sorted(
            dataset.scratch(target, alive, kind).name for kind in (dataset.WRITING, dataset.REPLACED)
        )
        assert (
            dataset.scratch(target, alive, dataset.WRITING) / "attitude.parquet"
        ).read_bytes() == b"half a partition"
        assert dataset.done_flights(out) == {dataset.flight_id(session)}
        again = _cli("batch", session, "--out", str(out), "-e", "dcm", "--scheduler", scheduler)
        assert "removed" not in again.stdout  # the live writer's folders stay while it writes
    finally:
        live.kill()
        live.wait(timeout=60)


def test_next_batch_removes_a_killed_runs_failure_file_and_sweep_folder_never_a_live_ones(flights, scheduler, tmp_path):
    """A failure's file and a sweep's folder are written under a temporary name too, held locked
    (dataset.write_locked): a writer killed with SIGKILL mid-write left them, and the next batch
    removes them as it removes a partition's (it left them for good before); another run's
    writers, alive, keep theirs."""
    out = tmp_path / "fleet"
    failure = dataset.failure_file(out, "junk.bin-0badc0de")
    sweep = out / dataset.SWEEPS / "dcm-20261205-090000"
    dead, alive = ("4242-deadbeef", "4343-a11ca7ed")
    writers = []
    try:
        for target, kind in ((failure, "file"), (sweep, "folder")):
            target.parent.mkdir(parents=True)
            for token in (dead, alive):
                writers.append(_writer(dataset.scratch(target, token, dataset.WRITING), kind))
        for killed in writers[0::2]:
            killed.kill()
            killed.wait(timeout=60)
        ran = _cli("batch", flights["sessions"][0], "--out", str(out), "-e", "dcm", "--scheduler", scheduler)
        gone = [dataset.scratch(target, dead, dataset.WRITING).name for target in (failure, sweep)]
        assert f"removed 2 temporary files and folders a killed run left in {out}: {', '.join(gone)}\n" in ran.stdout
        for target in (failure, sweep):
            left = [p.name for p in target.parent.iterdir() if p.name.startswith(".")]
            assert left == [dataset.scratch(target, alive, dataset.WRITING).name], left
        assert dataset.scratch(failure, alive, dataset.WRITING).read_bytes() == b"half a partition"
    finally:
        for writer in writers:
            writer.kill()
            writer.wait(timeout=60)


def test_rerun_skips_done_flights_and_force_redoes_them(batch, flights, scheduler):
    stamps = {f: os.stat(dataset.flight_dir(batch, f)).st_ino for f in dataset.done_flights(batch)}
    again = _cli("batch", *flights["good"], "--out", str(batch), "-e", "dcm", "--scheduler", scheduler)
    assert f"0 flights written, 0 failed, {len(flights['good'])} already" in again.stdout
    assert {f: os.stat(dataset.flight_dir(batch, f)).st_ino for f in stamps} == stamps
    one = flights["sessions"][1]
    forced = _cli("batch", one, "--out", str(batch), "-e", "dcm", "--scheduler", scheduler, "--force")
    assert "1 flights written" in forced.stdout
    redone = dataset.flight_id(one)
    assert os.stat(dataset.flight_dir(batch, redone)).st_ino != stamps[redone]
    assert dataset.done_flights(batch) == set(stamps)
    assert not [p for p in (batch / dataset.FLIGHTS).iterdir() if p.name.startswith(".")]


def test_a_run_whose_every_flight_failed_exits_1(tmp_path, scheduler):
    """A script running `gcs batch && gcs fleet report` stops there: nothing was written (it went on
    with exit 0). A run with some flights written and some failed still exits 0 (the test above)."""
    junk = tmp_path / "junk.bin"
    junk.write_bytes(b"not a log" * 100)
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["batch", str(junk), "--out", str(tmp_path / "ds"), "-e", "dcm", "--scheduler", scheduler])
    assert code == 1, (out.getvalue(), err.getvalue()[-2000:])
    assert "0 flights written, 1 failed" in out.getvalue() and "junk.bin" in err.getvalue()


def test_a_flight_without_imu_is_a_failure_row_as_replay_refuses_it(tmp_path, hop_without_imu, scheduler):
    """The hop's tlog without its IMU messages: `gcs batch` wrote it as a flight of 0 IMU samples
    and no error row (exit 0), where `gcs replay` and `gcs estimate` refuse it. It is a failure
    row with their reason."""
    path = hop_without_imu
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["batch", str(path), "--out", str(tmp_path / "ds"), "-e", "dcm", "--scheduler", scheduler])
    assert code == 1 and "0 flights written, 1 failed" in out.getvalue(), err.getvalue()[-2000:]
    why = f"{path}: offset 0: no IMU message ({', '.join(IMU_TYPES)}) in the log: nothing to estimate from"
    assert [r["reason"] for r in dataset.read_failures(tmp_path / "ds").table.to_pylist()] == [why]


def test_a_glob_or_folder_that_gives_no_flight_is_named(tmp_path, logs_dir, scheduler):
    """`gcs batch /media/sd/LOGS/*.BIN day2/ --out fleet` with the card not mounted: the glob
    matched nothing and was dropped without a word, as was a folder holding no log, and the run
    said "1 flights written" as if the fleet were complete."""
    (tmp_path / "day2").mkdir()
    (tmp_path / "day2" / "notes.txt").write_text("no log here")
    unmounted = str(tmp_path / "sd" / "*.BIN")
    ran = _cli(
        "batch", unmounted, str(tmp_path / "day2"), str(logs_dir / "ardupilot-fragment.bin"),
        "--out", str(tmp_path / "ds"), "-e", "dcm", "--scheduler", scheduler,
    )  # fmt: skip
    assert f"gcs batch: warning: {unmounted}: matches no file\n" in ran.stderr
    no_log = "no session folder or .tlog, .bin, .log, .ulg file there"
    assert f"gcs batch: warning: {tmp_path / 'day2'}: {no_log}\n" in ran.stderr
    assert "1 flights written, 0 failed" in ran.stdout


def test_a_scheduler_lost_mid_run_is_one_line_and_keeps_the_flights_written(tmp_path, logs_dir):
    """The scheduler killed after the first flight is written: `gcs batch` says so in one line
    (exit 2, no Dask traceback: it printed FutureCancelledError's), and the flights written before
    stay whole in the dataset for a re-run to skip."""
    port = free_port(socket.SOCK_STREAM)
    address = f"tcp://127.0.0.1:{port}"
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    scheduler = subprocess.Popen(
        [DASK, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"], **quiet
    )
    worker = subprocess.Popen(
        [DASK, "worker", address, "--nthreads", "1", "--no-nanny", "--host", "127.0.0.1", "--no-dashboard"], **quiet
    )
    hop = (logs_dir / "arducopter-sitl-hop.tlog").read_bytes()
    flights = []
    for k in range(8):  # one worker takes them one by one: the run is far from done after the first
        path = tmp_path / f"hop-{k}.tlog"
        path.write_bytes(hop)
        flights.append(str(path))
    out = tmp_path / "fleet"
    try:
        with Client(address, timeout="120s") as client:
            client.wait_for_workers(1, timeout=120)
        command = [sys.executable, "-m", "gcs", "batch", *flights, "--out", str(out), "--scheduler", address]
        run = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        first = run.stderr.readline()  # blocks until the first flight is written (or the run ends)
        assert first.startswith("ok "), first + run.stderr.read()
        scheduler.kill()
        stdout, rest = run.communicate(timeout=120)
    finally:
        for proc in (worker, scheduler):
            proc.kill()
            proc.wait()
    stderr = first + rest
    assert run.returncode == 2 and "Traceback" not in stderr, stderr[-3000:]
    last = stderr.strip().splitlines()[-1]
    assert last.startswith(f"gcs batch: error: {address}: lost the Dask scheduler after "), stderr[-3000:]
    written = [line for line in stderr.splitlines() if line.startswith("ok ")]
    assert len(written) < len(flights) and stdout == ""
    done = dataset.done_flights(out)  # and maybe one the worker wrote whose answer the scheduler took down
    assert {dataset.flight_id(line.split()[1].rstrip(":")) for line in written} <= done
    assert all((dataset.flight_dir(out, f) / "summary.parquet").is_file() for f in done)


def test_a_flight_whose_log_is_gone_is_still_on_the_fleet_report(tmp_path, logs_dir, scheduler):
    """The worst flight's log moved away after the batch: `gcs fleet report` failed whole in one
    line ("no such file or session folder", exit 2, no page), though the dataset holds all its page
    needs. The page is written; that flight is listed with why it has no report of its own."""
    logs = tmp_path / "logs"
    logs.mkdir()
    for name in ("ardupilot-fragment.bin", "arducopter-sitl-hop.tlog"):  # the fragment: far the worst
        shutil.copy(logs_dir / name, logs / name)
    out, page = tmp_path / "fleet", tmp_path / "fleet.html"
    _cli("batch", str(logs), "--out", str(out), "-e", "dcm", "--scheduler", scheduler)
    gone = logs / "ardupilot-fragment.bin"
    gone.unlink()
    done = _cli("fleet", "report", str(out), "--out", str(page), "--worst", "2")
    assert "wrote" in done.stderr and "(2 flights, 0 skipped)" in done.stderr
    text = page.read_text()
    assert f"{dataset.flight_id(gone)} (no report: {gone}: no such file or session folder)" in text
    kept = dataset.flight_id(logs / "arducopter-sitl-hop.tlog")
    assert f"href='fleet_flights/{kept}.html'" in text and (tmp_path / "fleet_flights" / f"{kept}.html").is_file()


def test_sweep_beats_a_bad_default_on_held_out_flights_and_its_preset_loads(batch, flights, scheduler, tmp_path):
    train, holdout = flights["sessions"][:2], flights["sessions"][2:]
    args = ["sweep", *train, "-e", "dcm", "--gain", "kp_rp=0.05:2.0", "--trials", "10", "--objective", "rms_vs_truth"]
    args += [a for h in holdout for a in ("--holdout", h)]
    done = _cli(*args, "--out", str(batch), "--scheduler", scheduler)
    assert "best for sim-quad-a" in done.stdout and "best for sim-quad-b" in done.stdout
    (folder,) = (batch / dataset.SWEEPS).iterdir()
    rows = pq.read_table(folder / "flights.parquet").to_pylist()
    held = [r for r in rows if r["holdout"]]
    assert sorted(r["path"] for r in held) == sorted(holdout)
    assert all(r["best"] < r["current"] for r in held), held
    assert pq.read_table(folder / "trials.parquet").num_rows == 10
    # the preset file is what `gcs estimate --preset-file` loads: same output as the gain by hand
    preset = folder / "preset.toml"
    best = next(line for line in preset.read_text().splitlines() if line.startswith("kp_rp"))
    tlog = str(Path(holdout[0]) / layout.TLOG)
    _cli("estimate", tlog, "--preset-file", str(preset), "--out", str(tmp_path / "a.csv"))
    _cli("estimate", tlog, "-e", "dcm", "--gain", best.replace(" ", ""), "--out", str(tmp_path / "b.csv"))
    _cli("estimate", tlog, "-e", "dcm", "--out", str(tmp_path / "c.csv"))
    a, b, c = ((tmp_path / f"{x}.csv").read_text() for x in "abc")
    assert a == b != c
    # the fleet page: every flight, the failure, the worst flight's own report, the sweep
    page = tmp_path / "fleet.html"
    _cli("fleet", "report", str(batch), "--out", str(page), "--worst", "1")
    text = page.read_text()
    assert all(dataset.flight_id(p) in text for p in flights["good"])
    assert "junk.bin" in text and folder.name in text and "<img src='data:image/png;base64," in text
    linked = list((tmp_path / "fleet_flights").glob("*.html"))
    assert len(linked) == 1 and linked[0].stem in text
    shutil.rmtree(tmp_path / "fleet_flights")


def test_a_sweep_whose_scheduler_does_not_answer_names_the_scheduler(tmp_path, logs_dir, capsys):
    """Nothing listens at the address: the one line names the scheduler, where the sweep's named
    its --out (the dataset folder, which was fine) for every cluster error."""
    address = f"tcp://127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    log = str(logs_dir / "arducopter-sitl-hop.tlog")
    args = ["sweep", log, "-e", "dcm", "--gain", "kp_rp=0.1:1", "--out", str(tmp_path / "ds"), "--scheduler", address]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"gcs sweep: error: {address}: "), err
    assert not (tmp_path / "ds").exists()


@pytest.mark.parametrize(
    ("text", "args", "error"),
    [
        ('estimator = "kf"\n[gains]\nr_roll = 0.1\n', ["-e", "dcm"], "is for kf, not --estimator dcm"),
        ('estimator = "dcm"\n[gains]\nkp_rp = "fast"\n', [], "[gains] must hold NAME = number lines"),
        ('estimator = "dcm"\n[gains]\nkp_rp = 900.0\n', [], "kp_rp: 900 1/s is outside"),
        ("estimator = dcm\n", [], "not TOML"),
    ],
)
def test_a_bad_preset_file_is_one_clear_line_and_no_output(tmp_path, logs_dir, capsys, text, args, error):
    preset, out = tmp_path / "p.toml", tmp_path / "out.csv"
    preset.write_text(text)
    hop = str(logs_dir / "arducopter-sitl-hop.tlog")
    assert main(["estimate", hop, "--preset-file", str(preset), *args, "--out", str(out)]) == 2
    assert error in capsys.readouterr().err and not out.exists()


def test_the_dashboard_starts_from_a_preset_file(tmp_path, udp_port):
    """`gcs serve/demo --preset-file`: the station's estimator starts with the file's gains, and
    the dashboard's gain listing shows them (a real Station, its real REST app)."""
    preset = PresetFile("dcm", "ardupilot", {"kp_rp": 0.37, "ki_rp": 0.02}, "from a sweep")
    station = Station(StationConfig(f"udpin:127.0.0.1:{udp_port}", presets=[preset]))
    api = TestClient(create_app(station, token="t"), base_url="http://127.0.0.1")
    listing = {e["name"]: e for e in api.get("/api/estimators").json()}
    gains = {g["name"]: g["value"] for g in listing["dcm"]["gains"]}
    assert (gains["kp_rp"], gains["ki_rp"]) == (0.37, 0.02)
    assert {g["name"]: g["value"] for g in listing["kf"]["gains"]} == registry.create("kf").gains.values
    (tmp_path / "p.toml").write_text(preset.to_toml())
    parsed = build_parser().parse_args(
        ["serve", "--connect", "udpin:127.0.0.1:1", "--preset-file", str(tmp_path / "p.toml")]
    )
    assert presets_or_report(parsed, "serve") == [preset]
