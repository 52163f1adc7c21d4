"""`gcs export --format mat|mcap`, the same from the REST route, and the notebook API
(`gcs.open_session`, `gcs.estimate`), on a session recorded from the real simulator in the test
and on the real logs in ../shared/data/logs. Expected values are read from the session's own
files (attitude.parquet, comparison.parquet, events.jsonl, telemetry.tlog) without the code under
test."""

from __future__ import annotations

import asyncio
import io
import json
import math
import shutil
import socket
import subprocess
import sys
from collections import Counter
from pathlib import Path

import httpx
import jsonschema
import numpy as np
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
import scipy.io
from live import running_station, sim_process, wait_for
from mcap.reader import make_reader
from pymavlink import mavutil

import gcs
from gcs.commands.cli import main
from gcs.core.samples import REBOOT_CLOCK_JUMP
from gcs.server.dashboard import DashboardServer
from gcs.sessions import layout
from gcs.transport.address import free_port


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> dict:
    """A session recorded from the simulator with a gain change and a note in it, and its .mat and
    .mcap as the REST route served them."""
    root = tmp_path_factory.mktemp("sessions")
    # the udp_port fixture is function-scoped; the session is recorded once for the module
    return asyncio.run(record(free_port(socket.SOCK_DGRAM), root))


async def record(port: int, root: Path) -> dict:
    async with (
        running_station(f"udpin:127.0.0.1:{port}", sessions_dir=str(root), record=True) as station,
        sim_process(f"udpout:127.0.0.1:{port}", profile="pixhawk", script="quad", speed=4.0),
    ):
        server = DashboardServer(station, port=0, viser=False)
        await server.start()
        try:
            await wait_for(lambda: station.estimation.pipeline.imu_samples > 300, 30, "IMU samples")
            station.set_gain("dcm", "kp_rp", 0.9, "test")
            station.add_note("gusty", "test")
            await wait_for(lambda: station.estimation.pipeline.imu_samples > 600, 30, "IMU samples after the gain")
            await station.stop_recording("test")
            (folder,) = [p for p in root.iterdir() if layout.is_session(p)]
            async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{server.port}", timeout=120) as api:
                rest = {}
                for fmt in ("mat", "mcap"):
                    response = await api.get(f"/api/sessions/{folder.name}/export", params={"format": fmt})
                    assert response.status_code == 200, response.text
                    assert response.headers["content-disposition"].endswith(f'.{fmt}"')
                    rest[fmt] = response.content
                bad = await api.get(f"/api/sessions/{folder.name}/export", params={"format": "xlsx"})
                assert bad.status_code == 422 and "mcap" in bad.text
        finally:
            await server.stop()
    return {"folder": folder, "rest": rest}


def parquet_attitude(folder: Path) -> dict[str, dict[str, np.ndarray]]:
    table = pq.read_table(folder / "attitude.parquet")
    out = {}
    for source in set(table["source"].to_pylist()):
        rows = table.filter(pc.equal(table["source"], source))
        out[source] = {c: rows[c].to_numpy() for c in ("t", "roll", "pitch", "yaw", "wall_time")}
    return out


def events_of(folder: Path) -> list[dict]:
    return [json.loads(line) for line in (folder / layout.EVENTS).read_text().splitlines()]


def check_mat(mat: dict, folder: Path) -> None:
    expected = parquet_attitude(folder)
    info = mat["info"][0, 0]
    names = {str(row[0][0]): str(row[1][0]) for row in info["sources"]}
    assert set(names) == set(expected) >= {"onboard", "truth", "dcm", "kf", "ekf"}
    for source, series in expected.items():
        struct = mat[names[source]][0, 0]
        np.testing.assert_array_equal(struct["t"].ravel(), series["t"])
        np.testing.assert_allclose(struct["roll"].ravel(), np.degrees(series["roll"]), rtol=0, atol=1e-12)
        np.testing.assert_allclose(struct["yaw"].ravel(), np.degrees(series["yaw"]), rtol=0, atol=1e-12)
    errors = mat["dcm"][0, 0]["errors"][0, 0]
    assert {"onboard", "truth"} <= set(errors.dtype.names)
    truth = errors["truth"][0, 0]
    err = np.column_stack([truth[a].ravel() for a in ("roll", "pitch", "yaw")])
    assert len(err) > 100 and np.all(np.abs(err) <= 180)
    np.testing.assert_allclose(truth["rms"].ravel(), np.sqrt(np.mean(err**2, axis=0)))
    gains = [e for e in events_of(folder) if e["kind"] == "gain"]
    changes = mat["gain_changes"][0, 0]
    assert len(gains) == 1 and changes["wall_time"].ravel().tolist() == [gains[0]["wall_time"]]
    assert [str(c[0]) for c in changes["gain"].ravel()] == ["kp_rp"]
    assert changes["new"].ravel().tolist() == [0.9]
    assert 0 < changes["t"].ravel()[0] < expected["dcm"]["t"][-1]  # on the vehicle clock, inside the session


def read_mcap(data: bytes) -> tuple[Counter, dict[str, list[dict]], list[int]]:
    """Messages per topic, the decoded messages, and log times in file order; every schema is
    checked as JSON Schema and every message validated against its channel's schema."""
    counts: Counter = Counter()
    messages: dict[str, list[dict]] = {}
    validators = {}
    log_times = []
    reader = make_reader(io.BytesIO(data))
    for schema, channel, message in reader.iter_messages(log_time_order=False):
        assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
        if schema.id not in validators:
            parsed = json.loads(schema.data)
            jsonschema.Draft202012Validator.check_schema(parsed)
            assert parsed["type"] == "object"
            validators[schema.id] = jsonschema.Draft202012Validator(parsed)
        decoded = json.loads(message.data)
        validators[schema.id].validate(decoded)
        counts[channel.topic] += 1
        messages.setdefault(channel.topic, []).append(decoded)
        log_times.append(message.log_time)
    return counts, messages, log_times


def tlog_imu_count(folder: Path) -> int:
    """IMU messages of the type the session estimated from, counted with pymavlink."""
    meta = json.loads((folder / layout.META).read_text())
    imu_type = meta["estimation"]["detected_imu_type"]
    log = mavutil.mavlink_connection(str(folder / layout.TLOG))
    n = 0
    while log.recv_match(type=imu_type) is not None:
        n += 1
    return n


def check_mcap(data: bytes, folder: Path) -> None:
    counts, messages, log_times = read_mcap(data)
    expected = parquet_attitude(folder)
    for source, series in expected.items():
        assert counts[f"/attitude/{source}"] == len(series["t"])
        got = messages[f"/attitude/{source}"]
        np.testing.assert_allclose([m["roll_deg"] for m in got], np.degrees(series["roll"]), atol=1e-9)
    imu = sum(n for topic, n in counts.items() if topic.startswith("/imu/"))
    assert imu == tlog_imu_count(folder) > 600
    comparison = pq.read_table(folder / "comparison.parquet")
    pairs = Counter(zip(comparison["estimator"].to_pylist(), comparison["reference"].to_pylist()))
    assert pairs and {f"/comparison/{e}/{r}": n for (e, r), n in pairs.items()} == {
        t: n for t, n in counts.items() if t.startswith("/comparison/")
    }
    events = events_of(folder)
    assert counts["/events"] == len(events) and any(m["event"].get("text") == "gusty" for m in messages["/events"])
    assert sum(counts.values()) == len(log_times)
    assert log_times == sorted(log_times)  # one timeline: everything on the vehicle clock
    t_end = max(s["t"][-1] for s in expected.values())
    assert all(0 < m["t"] <= t_end for m in messages["/attitude/dcm"])
    assert max(log_times) <= math.ceil(t_end + 60) * 1e9  # the wall-clock records were placed on it too


def test_mat_export_equals_the_sessions_parquet(recorded, tmp_path):
    out = tmp_path / "s.mat"
    assert main(["export", str(recorded["folder"]), "--format", "mat", "--out", str(out)]) == 0
    check_mat(scipy.io.loadmat(out), recorded["folder"])
    assert [p.name for p in tmp_path.iterdir()] == ["s.mat"]  # no temporary file left


def test_mcap_export_holds_every_series(recorded, tmp_path):
    out = tmp_path / "s.mcap"
    assert main(["export", str(recorded["folder"]), "--format", "mcap", "--out", str(out)]) == 0
    check_mcap(out.read_bytes(), recorded["folder"])


def test_rest_export_mat_and_mcap(recorded):
    check_mat(scipy.io.loadmat(io.BytesIO(recorded["rest"]["mat"])), recorded["folder"])
    check_mcap(recorded["rest"]["mcap"], recorded["folder"])


def test_failed_export_keeps_the_previous_file(tmp_path, capsys):
    out = tmp_path / "flight.mcap"
    out.write_bytes(b"previous export")
    bad = tmp_path / "broken.tlog"
    bad.write_bytes(b"\x00" * 64)
    assert main(["export", str(bad), "--format", "mcap", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bad) in err[0] and "MAVLink" in err[0]
    assert out.read_bytes() == b"previous export"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["broken.tlog", "flight.mcap"]


def test_open_session_gives_the_same_columns_for_every_input(recorded, logs_dir):
    inputs = [
        recorded["folder"],
        logs_dir / "arduplane-sitl-vtol.tlog",
        logs_dir / "ardupilot-fragment.bin",
        logs_dir / "px4-flight-sample.ulg",
    ]
    kinds, shapes = [], set()
    for path in inputs:
        s = gcs.open_session(path)
        kinds.append(s.kind)
        assert s.attitude.num_rows > 0 and s.estimators == ["dcm", "ekf", "kf"] and s.references
        dcm = s.source("dcm")
        steps = np.diff(dcm["t"].to_numpy())  # in time order within each boot (the vtol log's clock
        assert dcm.num_rows > 0 and np.all((steps >= 0) | (steps < -REBOOT_CLOCK_JUMP))  # steps back 1.4 s once)
        shapes.add(
            (
                tuple(s.attitude.column_names),
                tuple(dcm.column_names),
                tuple(s.comparison.column_names),
                tuple(s.errors().column_names),
                tuple(s.events.column_names),
                tuple(s.imu.column_names),
            )
        )
        assert s.errors().num_rows >= 3  # every estimator scored against a reference
    assert kinds == ["session", "tlog", "dataflash", "ulog"]
    assert len(shapes) == 1
    with pytest.raises(KeyError, match="dcm"):
        gcs.open_session(inputs[1]).source("nope")


def test_notebook_style_use(recorded):
    pd = pytest.importorskip("pandas")
    s = gcs.open_session(str(recorded["folder"]))
    dcm = s.attitude_df("dcm")
    truth = s.attitude_df("truth")
    assert isinstance(dcm, pd.DataFrame) and list(dcm.columns) == ["t", "boot", "wall_time", "roll", "pitch", "yaw"]
    # RMS roll error of DCM against the simulator's truth, each truth sample against the nearest estimate
    paired = pd.merge_asof(truth, dcm, on="t", direction="nearest", suffixes=("_truth", "_dcm"))
    rms = float(np.sqrt(((np.degrees(paired["roll_dcm"] - paired["roll_truth"])) ** 2).mean()))
    table = s.errors_df().set_index(["estimator", "reference"])
    assert 0 < rms < 20
    assert rms == pytest.approx(table.loc[("dcm", "truth"), "rms_roll"], rel=0.2, abs=0.2)
    # the gain change is in the events, and the comparison snapshots are there
    gains = s.events_df().query("kind == 'gain'")
    assert gains[["estimator", "gain", "new"]].values.tolist() == [["dcm", "kp_rp", 0.9]]
    assert len(s.comparison_df()) == pq.read_table(recorded["folder"] / "comparison.parquet").num_rows


def test_estimate_reproduces_the_live_estimator(recorded):
    folder = recorded["folder"]
    live = parquet_attitude(folder)["dcm"]
    again = gcs.estimate(folder, estimator="dcm")
    assert again.column_names == ["t", "roll", "pitch", "yaw"]
    np.testing.assert_array_equal(again["t"].to_numpy(), live["t"])
    np.testing.assert_allclose(again["roll"].to_numpy(), live["roll"], rtol=0, atol=1e-12)
    other = gcs.estimate(folder, estimator="dcm", gains={"kp_rp": 0.05})
    assert other.num_rows == again.num_rows
    assert not np.allclose(other["roll"].to_numpy(), again["roll"].to_numpy())


def test_matlab_names_are_valid_identifiers():
    from gcs.sessions.matfile import NAME_MAX, matlab_name

    taken: set[str] = {"info"}
    names = [matlab_name(n, taken) for n in ("dcm", "mag-test", "2nd imu", "info", "", "x" * 80, "x" * 80)]
    assert names[:5] == ["dcm", "mag_test", "x2nd_imu", "info_2", "x"]
    assert len(set(names)) == len(names) and all(len(n) <= NAME_MAX for n in names)
    assert all(n[0].isalpha() and n.replace("_", "").isalnum() for n in names)


def test_import_gcs_stays_cheap_and_pandas_is_optional(logs_dir, tmp_path):
    import os
    import subprocess
    import sys

    code = "import sys, gcs; print(gcs.__version__, 'pyarrow' in sys.modules, 'gcs.api' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out[1:] == ["False", "False"] and out[0]
    # Without pandas (a pandas that cannot be imported shadows the installed one) the tables still
    # work and a DataFrame asks for pandas by name.
    (tmp_path / "pandas").mkdir()
    (tmp_path / "pandas" / "__init__.py").write_text("raise ModuleNotFoundError(\"No module named 'pandas'\")\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")])}
    log = str(logs_dir / "ardupilot-fragment.bin")
    code = f"import gcs; s = gcs.open_session({log!r}); print(s.attitude.num_rows); s.attitude_df()"
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert run.returncode == 1 and int(run.stdout) > 0, run.stderr
    assert run.stderr.strip().splitlines()[-1] == (
        "ImportError: gcs: DataFrames need pandas, which is not installed (pip install pandas)"
    )


@pytest.mark.parametrize("fmt", ["mat", "csv"])
def test_a_damaged_sessions_parquet_is_a_one_line_error(recorded, tmp_path, fmt, capsys):
    """A session copied off a card whose attitude.parquet got cut: `gcs export` said a pyarrow
    traceback ("Parquet magic bytes not found in footer"); it is one line naming the file, and the
    previous export stays (found by auditing with a truncated copy of a recorded session)."""
    folder = tmp_path / recorded["folder"].name
    shutil.copytree(recorded["folder"], folder)
    parquet = folder / "attitude.parquet"
    parquet.write_bytes(parquet.read_bytes()[:1000])
    out = tmp_path / f"flight.{fmt}"
    out.write_bytes(b"previous export")
    assert main(["export", str(folder), "--format", fmt, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"gcs export: error: {parquet}: unreadable Parquet"), err
    assert out.read_bytes() == b"previous export"


def test_a_session_without_its_attitude_table_exports_the_replayed_one(recorded, tmp_path):
    """A copy of a session without attitude.parquet: its tlog replayed gives the attitudes it
    recorded (0 rows were exported), the wall time unknown."""
    folder = tmp_path / recorded["folder"].name
    shutil.copytree(recorded["folder"], folder)
    (folder / "attitude.parquet").unlink()
    out = tmp_path / "flight.mat"
    assert main(["export", str(folder), "--format", "mat", "--out", str(out)]) == 0
    mat, expected = scipy.io.loadmat(out), parquet_attitude(recorded["folder"])
    names = {str(row[0][0]): str(row[1][0]) for row in mat["info"][0, 0]["sources"]}
    assert set(names) == set(expected) >= {"onboard", "truth", "dcm", "kf", "ekf"}
    for source, series in expected.items():
        struct = mat[names[source]][0, 0]
        np.testing.assert_array_equal(struct["t"].ravel(), series["t"])
        np.testing.assert_array_equal(struct["roll"].ravel(), np.degrees(series["roll"]))


def test_mcap_of_a_tlog_with_a_damaged_timestamp(logs_dir, tmp_path):
    """One flipped bit put an ATTITUDE record's tlog stamp 2285 years ahead: its publish time in
    ns no longer fits MCAP's uint64 and `gcs export --format mcap` stopped with struct.error's
    traceback (found by the audit). The message is written, its time clamped into the range."""
    from gcs.mavlink.framing import MavlinkDecoder
    from gcs.mavlink.tlog import read_tlog_records

    source = logs_dir / "arducopter-sitl-hop.tlog"
    data = bytearray(source.read_bytes())
    decoder = MavlinkDecoder()
    records = list(read_tlog_records(source).records())
    offset = next(
        offset
        for offset, _, packet in records[len(records) // 2 :]
        if [kind for _, kind, _, _ in decoder.frames(packet, final=True)] == ["ATTITUDE"]
    )
    stamp = offset - 8  # the record's 8-byte big-endian µs before its packet
    data[stamp : stamp + 8] = (int.from_bytes(data[stamp : stamp + 8], "big") ^ (1 << 56)).to_bytes(8, "big")
    path, out = tmp_path / "flipped-stamp.tlog", tmp_path / "flipped-stamp.mcap"
    path.write_bytes(bytes(data))
    done = subprocess.run(
        [sys.executable, "-m", "gcs", "export", str(path), "--format", "mcap", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    with out.open("rb") as fh:
        written = sum(1 for _ in make_reader(fh).iter_messages())
    assert done.stderr.strip().splitlines() == [f"{out}: {written} messages"]


@pytest.mark.parametrize("fmt", ["csv", "parquet", "mat", "mcap"])
def test_an_export_that_cannot_be_created_names_the_file_asked_for(logs_dir, fmt, capsys):
    """A folder where no file can be made (/proc, for root too; a read-only folder): CSV and
    Parquet said "Failed to open local file '/proc/.x.csv.8252-40d47174.tmp'. Detail: [errno 2]
    ...", the temporary file pyarrow was given, never the --out the user wrote."""
    out = f"/proc/gcs-export.{fmt}"
    assert main(["export", str(logs_dir / "ardupilot-fragment.bin"), "--format", fmt, "--out", out]) == 2
    assert capsys.readouterr().err == f"gcs export: error: {out}: No such file or directory\n"
