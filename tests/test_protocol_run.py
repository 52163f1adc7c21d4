"""`gcs protocol run` end to end: seed 000's bench protocol against the simulator's `bench`
script, unattended (stdin closed), with dcm deliberately mis-tuned through the gain option; the
session it records, and the tables recomputed from it by `gcs protocol report`."""

from __future__ import annotations

import csv
import json
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from gcs.transport.address import free_port

GCS = [sys.executable, "-m", "gcs"]
#: The bench script lasts 123 vehicle seconds; 4x keeps a loaded 2-core machine from losing
#: UDP bursts while still finishing in about half a minute.
SPEED = "4"


@pytest.fixture(scope="module")
def bench_run(tmp_path_factory):
    """One unattended run of the seed000-bench protocol: (completed process, session folder)."""
    root = tmp_path_factory.mktemp("protocol")
    port = free_port(socket.SOCK_DGRAM)
    run = subprocess.Popen(
        GCS
        + ["protocol", "run", "seed000-bench", "--connect", f"udpin:127.0.0.1:{port}", "--detect-source", "truth"]
        + ["--gain", "dcm.kp_rp=0", "--gain", "dcm.ki_rp=0", "--timeout", "150", "--record-dir", str(root)],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert run.stdout is not None
    first = run.stdout.readline()  # the first prompt: the station is up and listening
    assert first.startswith("step 1/9"), first
    sim = subprocess.Popen(
        GCS + ["sim", "--script", "bench", "--speed", SPEED, "--link", f"udpout:127.0.0.1:{port}"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        out, err = run.communicate(timeout=200)
    finally:
        sim.terminate()
        sim.wait(10)
        if run.poll() is None:
            run.kill()
    (folder,) = [p for p in root.iterdir() if p.is_dir()]
    return run.returncode, first + out, err, folder


def _steps(path: Path) -> list[dict[str, str]]:
    with path.open() as fh:
        return [row for row in csv.DictReader(fh) if row["table"] == "steps"]


def test_bench_protocol_completes_unattended_and_truth_meets_the_target(bench_run):
    code, out, err, folder = bench_run
    assert code == 0, err
    events = [json.loads(line) for line in (folder / "events.jsonl").read_text().splitlines()]
    holds = [e for e in events if e["kind"] == "protocol" and e["action"] == "hold"]
    assert [h["index"] for h in holds] == list(range(9))
    assert all(h["t_hold_end"] - h["t_hold_start"] >= 3.0 for h in holds)
    rows = _steps(folder / "protocol.csv")
    truth = [r for r in rows if r["source"] == "truth"]
    assert [(r["axis"], float(r["target_deg"])) for r in truth] == [
        ("roll", -30.0),
        ("roll", -45.0),
        ("roll", -60.0),
        ("pitch", 30.0),
        ("pitch", 45.0),
        ("pitch", 60.0),
        ("yaw", -30.0),
        ("yaw", -45.0),
        ("yaw", 60.0),
    ]
    assert all(float(r["mre_last_pct"]) < 0.5 for r in truth), [r["mre_last_pct"] for r in truth]
    # dcm without its roll-pitch correction drifts with the simulated gyro bias
    dcm = [float(r["mre_last_pct"]) for r in rows if r["source"] == "dcm" and r["axis"] != "yaw"]
    assert len(dcm) == 6
    assert sum(dcm) / len(dcm) > 1.0
    assert max(float(r["mre_last_pct"]) for r in truth) < min(dcm)
    gains = [e for e in events if e["kind"] == "gain" and e["estimator"] == "dcm"]
    assert {(g["gain"], g["new"]) for g in gains} >= {("kp_rp", 0.0), ("ki_rp", 0.0)}


def test_protocol_report_recomputes_the_run_from_the_session(bench_run, tmp_path):
    folder = bench_run[3]
    out = tmp_path / "again.csv"
    done = subprocess.run(
        GCS + ["protocol", "report", str(folder), "--csv", str(out)], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert "roll mean" in done.stdout and "accel_mag" in done.stdout
    assert out.read_text() == (folder / "protocol.csv").read_text()
