"""`gcs protocol run` end to end: seed 000's bench protocol against the simulator's `bench`
script, unattended (stdin closed), with dcm deliberately mis-tuned through the gain option; the
session it records, and the tables recomputed from it by `gcs protocol report`."""

from __future__ import annotations

import csv
import json
import math
import socket
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
import scipy.io

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


class _Tables(HTMLParser):
    """The cells of every <table class=...> of a page, by class."""

    def __init__(self) -> None:
        super().__init__()
        self.tables: dict[str, list[list[str]]] = {}
        self._current: list[list[str]] | None = None
        self._cell: list[str] | None = None

    def handle_starttag(self, tag, attrs):
        if tag == "table":
            self._current = self.tables.setdefault(dict(attrs).get("class") or "", [])
        elif tag == "tr" and self._current is not None:
            self._current.append([])
        elif tag in ("td", "th"):
            self._cell = []

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None and self._current is not None:
            self._current[-1].append("".join(self._cell))
            self._cell = None
        elif tag == "table":
            self._current = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell.append(data)


def _same(a: str, b: float) -> bool:
    """An HTML cell (3 decimals, a dash for NaN) shows the number b."""
    if math.isnan(b):
        return a == "–"
    return abs(float(a) - b) <= 0.0005 + 1e-9 * abs(b)


def test_protocol_tables_agree_in_csv_html_and_mat(bench_run, tmp_path):
    folder = bench_run[3]
    again, page, mat = tmp_path / "again.csv", tmp_path / "report.html", tmp_path / "run.mat"
    commands = [
        ["protocol", "report", str(folder), "--csv", str(again)],
        ["report", str(folder), "--out", str(page)],
        ["export", str(folder), "--format", "mat", "--out", str(mat)],
    ]
    for command in commands:
        done = subprocess.run(GCS + command, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr
    # the report command recomputes the live run's file exactly from the session
    assert again.read_text() == (folder / "protocol.csv").read_text()
    with (folder / "protocol.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    steps = [r for r in rows if r["table"] == "steps"]
    mse = [r for r in rows if r["table"] == "mse"]
    assert {r["source"] for r in steps} >= {"truth", "onboard", "ahrs2", "dcm", "kf", "ekf", "accel_mag"}

    parser = _Tables()
    parser.feed(page.read_text())
    html_steps = parser.tables["protocol-steps"]
    header, body = html_steps[0], html_steps[1:]
    assert len(body) == len(steps)
    for cells, row in zip(body, steps):
        shown = dict(zip(header, cells))
        assert shown["source"] == row["source"] and int(shown["step"]) == int(row["step"])
        for name in ("mre_last_pct", "mre_hold_pct", "abs_err_last_deg", "mse_roll", "mse_pitch", "mse_yaw", "rise_s"):
            assert _same(shown[name], float(row[name] or "nan")), (name, shown[name], row[name])
    html_mse = parser.tables["protocol-mse"]
    for cells, row in zip(html_mse[1:], mse, strict=True):
        shown = dict(zip(html_mse[0], cells))
        assert shown["source"] == row["source"]
        for name in ("mse_roll", "mse_pitch", "mse_yaw", "reduction_roll_pct", "reduction_pitch_pct"):
            assert _same(shown[name], float(row[name] or "nan")), (name, shown[name], row[name])

    variables = scipy.io.loadmat(mat, simplify_cells=True)["protocol"]
    assert list(variables["steps"]["source"]) == [r["source"] for r in steps]
    for name in ("mre_last_pct", "abs_err_hold_deg", "mse_yaw", "settling_s", "cross_deg"):
        np.testing.assert_array_equal(variables["steps"][name], [float(r[name] or "nan") for r in steps])
    np.testing.assert_array_equal(
        variables["mse"]["reduction_roll_pct"], [float(r["reduction_roll_pct"] or "nan") for r in mse]
    )
