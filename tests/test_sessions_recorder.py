"""Recording: a session survives kill -9 and is recovered on the next start; a full disk stops
the recording with a clear error while the live view keeps running and the files stay valid."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import importlib.metadata
import json
import resource
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import ROOT, free_port
from live import running_sim, running_station, wait_for
from pymavlink import mavutil

from gcs import __version__ as GCS_VERSION
from gcs.logs.logfile import InputError
from gcs.mavlink.decoding import decode
from gcs.mavlink.tlog import read_tlog_records
from gcs.sessions import columnar, layout
from gcs.sessions.contents import read_events
from gcs.sessions.recovery import recover_sessions
from gcs.sessions.sources import open_source

PY = sys.executable
#: Our heartbeats (1 Hz) the recording holds on disk before the kill: the stretch recorded is this
#: much of the station's own clock, however slowly a loaded machine runs it.
SENT_HEARTBEATS = 6
SIM_SPEED = 2.5


def _spawn(*args: str) -> subprocess.Popen:
    return subprocess.Popen([PY, "-m", "gcs", *args], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def _one_session(root: Path) -> Path:
    sessions = [p for p in root.iterdir() if layout.is_session(p)]
    assert len(sessions) == 1, sessions
    return sessions[0]


def _sent_heartbeats(records) -> int:
    """Our heartbeats among a .tlog's records: sent packets are marked in the stamp's low bits."""
    return sum(1 for usec, packet in records if usec & 3 == 3 and decode(packet).get_type() == "HEARTBEAT")


def _recorded_so_far(root: Path) -> tuple[int, int]:
    """(our heartbeats in the .tlog, attitude rows in the live stream file) of the session being
    recorded under root; (0, 0) before it has both files. Read while the recorder writes: an
    incomplete last record or batch is left out."""
    sessions = [p for p in root.iterdir() if layout.is_session(p)] if root.is_dir() else []
    if len(sessions) != 1 or not (sessions[0] / layout.TLOG).exists():
        return 0, 0
    sent = _sent_heartbeats(read_tlog_records(sessions[0] / layout.TLOG))
    attitude = layout.stream_path(sessions[0], "attitude")
    return sent, columnar.read_stream(attitude, columnar.ATTITUDE_SCHEMA)[0].num_rows


def _pymavlink_count(path: Path) -> int:
    conn = mavutil.mavlink_connection(str(path), robust_parsing=True)
    n = 0
    while conn.recv_msg() is not None:
        n += 1
    return n


def test_kill9_loses_under_a_second_and_session_is_recovered(tmp_path):
    port = free_port()
    root = tmp_path / "sessions"
    sim = _spawn("sim", "--link", f"udpout:127.0.0.1:{port}", "--script", "quad", "--speed", str(SIM_SPEED))
    gcs = _spawn(
        "status", "--connect", f"udpin:127.0.0.1:{port}", "--duration", "60", "--record", "--record-dir", str(root)
    )
    try:
        deadline = time.monotonic() + 120  # two interpreters starting on a loaded machine, then the stretch
        while (recorded := _recorded_so_far(root))[0] < SENT_HEARTBEATS or recorded[1] == 0:
            assert time.monotonic() < deadline, f"(heartbeats, attitude rows) recorded: {recorded}"
            assert gcs.poll() is None, gcs.stderr.read().decode()
            time.sleep(0.2)  # polling files another process writes: the condition is the deadline above
        killed_at = time.time()
        gcs.send_signal(signal.SIGKILL)
        gcs.wait(5)
    finally:
        for proc in (gcs, sim):
            if proc.poll() is None:
                proc.kill()
                proc.wait(5)

    folder = _one_session(root)
    assert layout.read_meta(folder)["end"] is None  # left open by the crash
    tlog = folder / layout.TLOG
    records = read_tlog_records(tlog)
    stamps = [usec for usec, _ in records]
    assert records.skipped == 0 and records.truncated_at is None, (records.skipped, records.truncated_at)
    assert _pymavlink_count(tlog) == len(stamps)
    last = max(u & ~3 for u in stamps) / 1e6
    lost = killed_at - last
    print(f"\nkill -9 after {recorded[0]} heartbeats: {len(stamps)} records, last record {lost:.3f} s before the kill")
    assert lost < 1.0
    assert _sent_heartbeats(records) >= SENT_HEARTBEATS  # our heartbeats, marked as sent
    assert columnar.read_stream(layout.stream_path(folder, "attitude"), columnar.ATTITUDE_SCHEMA)[0].num_rows > 0

    async def restart() -> dict:
        async with running_station(f"udpin:127.0.0.1:{free_port()}", sessions_dir=str(root), record=True) as station:
            return dataclasses.asdict(station.recorder.snapshot())

    status = asyncio.run(restart())
    assert [r["session"] for r in status["recovered"]] == [folder.name]
    meta = layout.read_meta(folder)
    assert meta["recovered"] is True
    assert meta["end"] == pytest.approx(last, abs=1e-6)
    made = meta["provenance"]  # which code recorded it, checked against git itself
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    assert made["version"] == GCS_VERSION and made["commit"].startswith(head)
    assert made["dependencies"]["pymavlink"] == importlib.metadata.version("pymavlink")
    assert columnar.read_table(folder, "attitude").num_rows > 0
    assert not layout.stream_path(folder, "attitude").exists()
    events = [json.loads(line) for line in (folder / layout.EVENTS).read_text().splitlines()]
    assert events[-1]["event"] == "recovered"
    assert len(layout.list_sessions(root)) == 1  # the old one kept; the new station heard nothing: no folder


@contextlib.contextmanager
def _small_disk(path: Path, size: str = "64k"):
    """A 64 KiB tmpfs at path; without permission to mount, RLIMIT_FSIZE gives the same EFBIG-style
    write error for files over the limit."""
    path.mkdir()
    mounted = (
        subprocess.run(
            ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], capture_output=True
        ).returncode
        == 0
    )
    if mounted:
        try:
            yield "tmpfs"
        finally:
            subprocess.run(["umount", "-l", str(path)], check=False)
        return
    old_limit = resource.getrlimit(resource.RLIMIT_FSIZE)
    old_handler = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (64 * 1024, old_limit[1]))
    try:
        yield "rlimit"
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, old_limit)
        signal.signal(signal.SIGXFSZ, old_handler)


def test_full_disk_gives_clear_error_and_keeps_valid_files(tmp_path):
    disk = tmp_path / "disk"
    port = free_port()

    async def record() -> tuple[dict, int, int, list]:
        async with running_sim(f"udpout:127.0.0.1:{port}", profile="pixhawk", script="quad", speed=4.0):
            async with running_station(f"udpin:127.0.0.1:{port}", sessions_dir=str(disk), record=True) as station:
                await wait_for(lambda: station.recorder.state == "failed", 30, "the disk to fill")
                imu_at_failure = station.estimation.pipeline.imu_samples
                pipeline = station.estimation.pipeline
                await wait_for(lambda: pipeline.imu_samples > imu_at_failure + 20, 10, "estimation after the failure")
                events = [e.as_dict() for e in station.events.recent if e.kind == "recording"]
                return (
                    dataclasses.asdict(station.recorder.snapshot()),
                    imu_at_failure,
                    station.estimation.pipeline.imu_samples,
                    events,
                )

    with _small_disk(disk) as how:
        status, imu_at_failure, imu_later, events = asyncio.run(record())
        print(f"\nfull disk via {how}: {status['error']}")
        assert status["state"] == "failed"
        assert "cannot write" in status["error"] and (
            "No space left" in status["error"] or "too large" in status["error"]
        )
        assert any(e.get("event") == "error" for e in events)
        assert imu_later > imu_at_failure  # the live estimation kept running
        folder = _one_session(disk)
        tlog = folder / layout.TLOG
        records = read_tlog_records(tlog)
        n = sum(1 for _ in records)
        assert n > 0 and records.skipped == 0 and records.truncated_at is None
        assert _pymavlink_count(tlog) == n
        for line in (folder / layout.EVENTS).read_text().splitlines():
            json.loads(line)
        assert "error" in layout.read_meta(folder) or layout.read_meta(folder)["end"] is None


def test_unwritable_folder_is_reported_not_raised(tmp_path):
    blocked = tmp_path / "file-not-dir"
    blocked.write_text("")

    async def run() -> dict:
        async with running_station(
            f"udpin:127.0.0.1:{free_port()}", sessions_dir=str(blocked / "sessions"), record=True
        ) as st:
            return dataclasses.asdict(st.recorder.snapshot())  # start() reported it synchronously

    status = asyncio.run(run())
    assert status["state"] == "failed"
    assert str(blocked) in status["error"]


@pytest.mark.parametrize("bad", [b"{bad", b"[1]", b"null", b'{"start": "abc", "end": [], "vehicle": 5}'])
def test_a_malformed_meta_json_does_not_stop_start_up(tmp_path, bad):
    damaged = tmp_path / "2026-01-01_00-00-00_x"
    damaged.mkdir()
    (damaged / layout.META).write_bytes(bad)
    listing = subprocess.run(
        [PY, "-m", "gcs", "sessions", "--dir", str(tmp_path), "--json"], capture_output=True, text=True, timeout=60
    )
    assert listing.returncode == 0 and json.loads(listing.stdout)[0]["name"] == damaged.name, listing.stderr

    async def start() -> str:
        async with running_station(
            f"udpin:127.0.0.1:{free_port()}", sessions_dir=str(tmp_path), record=True
        ) as station:
            return station.recorder.snapshot().state

    assert asyncio.run(start()) == "waiting"  # started (not failed), the session opens at the first byte
    if bad.startswith(b'{"'):  # an object: recovered (closed), every field it had kept as it was
        meta = json.loads((damaged / layout.META).read_bytes())
        assert meta["vehicle"] == 5 and meta["recovered"] is True and meta["end"] is None
    else:  # not an object: reported, left as it was
        assert (damaged / layout.META).read_bytes() == bad


def test_a_session_whose_meta_json_is_unreadable_is_listed_as_damaged_not_open(tmp_path):
    """`gcs sessions` showed a session with a garbled meta.json as "open (recording, or left by a
    crash)", the state the next start recovers, but recovery cannot mend it and replay and report
    refuse it: the engineer waited for a recovery that never came. It is listed as damaged, why."""
    damaged = tmp_path / "2026-01-01_00-00-00_x"
    damaged.mkdir()
    (damaged / layout.META).write_bytes(b'{"start": 1767225600, "end"')  # cut by a failing card
    listing = subprocess.run(
        [PY, "-m", "gcs", "sessions", "--dir", str(tmp_path)], capture_output=True, text=True, timeout=60
    )
    assert listing.returncode == 0, listing.stderr
    row = listing.stdout.splitlines()[1]
    assert row.startswith(damaged.name) and "open" not in row
    assert row.endswith(
        f"damaged: {damaged / layout.META}: unreadable meta.json (Expecting ':' delimiter: line 1 column 28 (char 27))"
    )
    (info,) = layout.list_sessions(tmp_path)
    assert info.error is not None and info.error in row


def test_links_inside_a_session_folder_are_never_followed(tmp_path, logs_dir):
    """A session folder from a stick may link to any file of this machine: replay, the event reader
    and crash recovery refuse the link with one line, and never read or append to its target."""
    secret = tmp_path / "secret.txt"
    secret.write_text('{"kind": "gain", "input_index": 0, "estimator": "dcm", "gain": "kp_rp", "new": 9}\n')
    folder = tmp_path / "sessions" / "2026-01-01_00-00-00_linked"
    folder.mkdir(parents=True)
    (folder / layout.META).write_text(json.dumps({"start": "2026-01-01T00:00:00", "end": None, "vehicle": "x"}))
    shutil.copy(logs_dir / "arducopter-sitl-hop.tlog", folder / layout.TLOG)
    (folder / layout.EVENTS).symlink_to(secret)

    with pytest.raises(InputError, match="symbolic link"):
        open_source(folder)
    with pytest.raises(InputError, match="symbolic link"):
        read_events(folder)
    replay = subprocess.run([PY, "-m", "gcs", "replay", str(folder), "--fast"], capture_output=True, text=True)
    assert replay.returncode == 2 and "symbolic link" in replay.stderr and "Traceback" not in replay.stderr

    reports = recover_sessions(folder.parent)  # left open: recovery would append its line to events.jsonl
    assert len(reports) == 1 and "symbolic link" in reports[0]["error"]
    assert secret.read_text().count("\n") == 1  # the target is untouched

    (folder / layout.EVENTS).unlink()
    (folder / layout.META).rename(tmp_path / "meta.json")
    (folder / layout.META).symlink_to(tmp_path / "meta.json")
    assert "symbolic link" in layout.read_meta(folder)["error"]  # the session is listed as damaged


def test_two_vehicles_starting_in_one_second_each_get_their_label(tmp_path):
    """Each vehicle's session folder starts as `<stamp>_unknown` until its heartbeat names it; two
    vehicles heard in the same second make `<stamp>_unknown` and `<stamp>_unknown-2`, and the
    second must be renamed too (found by auditing `gcs demo --vehicles apm25:1,pixhawk:2`: its
    sysid 2 session stayed `..._unknown-2`). The -2 of a name taken twice stays unique."""
    root = tmp_path / "sessions"
    for stamp in ("2026-05-01_10-00-00_unknown", "2026-05-01_10-00-00_unknown-2"):
        assert layout.labelled(stamp, "ArduPilot-QUADROTOR-2") == "2026-05-01_10-00-00_ardupilot-quadrotor-2"
    assert layout.labelled("2026-05-01_10-00-00_ardupilot-quadrotor-1", "ArduPilot-QUADROTOR-2") is None
    assert layout.labelled("2026-05-01_10-00-00_unknown-vehicle", "x") is None

    port, viser = free_port(), free_port()
    demo = [sys.executable, "-m", "gcs", "demo", "--vehicles", "apm25:1,pixhawk:2", "--duration", "8"]
    demo += ["--record-dir", str(root), "--port", str(port), "--viser-port", str(viser)]
    done = subprocess.run(demo, capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    folders = sorted(p for p in root.iterdir() if layout.is_session(p))
    labels = [json.loads((f / layout.META).read_text())["vehicle"]["label"] for f in folders]
    assert sorted(labels) == ["ArduPilot-QUADROTOR-1", "ArduPilot-QUADROTOR-2"], labels
    for folder, label in zip(folders, labels, strict=True):
        assert folder.name.split("_", 2)[2] == layout.safe_label(label), [f.name for f in folders]


def test_the_event_log_follows_the_session_folder_to_its_vehicle_name(tmp_path, udp_port):
    """Found by auditing an ArduPlane session: its events.jsonl (and gcs report) named the folder
    ".../2026-12-05_05-42-48_unknown" at the start, a folder that never existed by the time anyone
    read it: the session opens at the link's first byte, before the heartbeat names the vehicle,
    and is then moved to ".../..._ardupilot-quadrotor-1". A `renamed` event now says where."""
    root = tmp_path / "sessions"

    async def record() -> None:
        async with (
            running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk"),
            running_station(
                f"udpin:127.0.0.1:{udp_port}", sessions_dir=str(root), record=True, estimate=False
            ) as station,
        ):

            def moved() -> bool:
                session = station.recorder.session
                return session is not None and session.folder.name.endswith("_ardupilot-quadrotor-1")

            await wait_for(moved, 60, "the folder moved to the vehicle's name")

    asyncio.run(record())
    folder = _one_session(root)
    assert folder.name.endswith("_ardupilot-quadrotor-1"), folder
    recording = [e for e in read_events(folder) if e["kind"] == "recording"]
    assert [e["event"] for e in recording] == ["start", "renamed", "stop"], recording
    start, moved, stop = recording
    assert moved["old"] == start["folder"] and not Path(start["folder"]).exists(), recording
    assert Path(moved["folder"]) == Path(stop["folder"]) == folder, recording


def test_recording_ignores_what_the_working_directory_holds(tmp_path, udp_port, monkeypatch):
    """The writer named each table's file by building its path against the working directory, and
    the symlink check on that path ran there: a station started in a folder holding a link named
    like a table's stream (attitude.arrows) stopped recording at its first flush. The names are
    names now; the checks belong to the session's own folder."""
    root = tmp_path / "sessions"
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    (cwd / layout.stream_name("attitude")).symlink_to(tmp_path / "elsewhere")
    monkeypatch.chdir(cwd)

    async def record() -> None:
        async with (
            running_sim(f"udpout:127.0.0.1:{udp_port}", profile="pixhawk"),
            running_station(f"udpin:127.0.0.1:{udp_port}", sessions_dir=str(root), record=True) as station,
        ):

            def attitude_written_or_failed() -> bool:
                session = station.recorder.session
                if station.recorder.snapshot().state == "failed":
                    return True
                return session is not None and layout.stream_path(session.folder, "attitude").exists()

            await wait_for(attitude_written_or_failed, 120, "the attitude stream written (or the recording failed)")
            assert station.recorder.snapshot().error is None, station.recorder.snapshot()

    asyncio.run(record())
    assert columnar.read_table(_one_session(root), "attitude").num_rows > 0


def test_a_meta_json_that_does_not_fit_leaves_the_last_one_and_no_temporary_file(tmp_path):
    """A full disk while meta.json is replaced: the last complete meta.json stays, its temporary
    file goes (a 0-byte meta.json.tmp stayed in the session before), and the error says both in
    one line (what the recorder reports: "cannot write meta.json: ...")."""
    disk = tmp_path / "disk"
    with _small_disk(disk):
        folder = disk / "session"
        folder.mkdir()
        layout.write_meta(folder, {"start": 1.0, "end": None})
        with contextlib.suppress(OSError), open(disk / "filler", "wb", buffering=0) as filler:
            while True:  # until the disk is full (or, under RLIMIT_FSIZE, the file at its limit)
                filler.write(bytes(4096))
        with pytest.raises(OSError) as failed:
            layout.write_meta(folder, {"start": 1.0, "end": 2.0, "params": {f"P{i}": i for i in range(20_000)}})
        left = sorted(p.name for p in folder.iterdir())
        meta = layout.read_meta(folder)
        tmp_size = [p.stat().st_size for p in folder.iterdir() if p.name.endswith(".tmp")]
    message = str(failed.value)
    print(f"\n{message}")
    assert left == [layout.META], (left, tmp_size)
    assert meta == {"start": 1.0, "end": None}
    assert "meta.json left as it was, its temporary file removed" in message and "\n" not in message
