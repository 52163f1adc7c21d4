"""Scoring across a reboot, on real data: the SITL hop's tlog cut after BOOT_S s of its clock and
followed by the whole hop again, as a vehicle rebooted after a parameter change (its clock from
its start again), the second copy's IMU messages of its first IMU_LATE_S s cut out. ArduCopter
sends a slot's AHRS2 and ATTITUDE before its RAW_IMU, so a new boot's first references always
come before its first IMU sample; here its first second of them does. Every figure is checked against errors
computed here, with scipy's slerp, from the estimator's points: each reference scored against the
estimator's outputs around it in its own boot, one outside its boot's outputs not at all."""

from __future__ import annotations

import json
import math
import shutil
import struct

import matplotlib.axes
import matplotlib.figure
import numpy as np
import pytest
import scipy.io
from mcap.reader import make_reader
from pymavlink import mavutil
from scipy.spatial.transform import Rotation, Slerp

import gcs
from gcs.batch.flight import facts
from gcs.batch.sweep import score_flight
from gcs.commands.cli import main
from gcs.core.estimation import compare_stream
from gcs.core.estimators import registry
from gcs.runtime.replay import session_table, whole_table
from gcs.sessions import report
from gcs.sessions.contents import open_contents
from gcs.sessions.protocol import session_tables
from gcs.sessions.sources import open_source
from gcs.sessions.whatif import run_estimator, what_if

#: Vehicle seconds of the first boot (from the hop's first message at 5.7 s): shorter than the
#: comparison's 30 s history, so the old boot's estimates still cover the new boot's first times.
BOOT_S = 25.0
#: s of the new boot's clock during which it sends its attitudes (AHRS2, ATTITUDE) but no IMU yet
IMU_LATE_S = 1.0
NAMES = ["dcm", "ekf"]
REFERENCES = ("onboard", "ahrs2", "truth")


def rebooted_hop(logs_dir, out, left_out: tuple[str, ...] = ()):
    """The hop's records while its clock is at most BOOT_S (but the message types `left_out`),
    then all of them again, the second copy's record times moved on to follow the first's."""
    conn = mavutil.mavlink_connection(str(logs_dir / "arducopter-sitl-hop.tlog"), robust_parsing=True)
    records, clock, imu, kinds = [], [], [], []
    latest = 0.0
    while (msg := conn.recv_msg()) is not None:
        if msg.get_type() == "BAD_DATA":
            continue
        if msg.get_srcSystem() == 1 and hasattr(msg, "time_boot_ms"):
            latest = msg.time_boot_ms / 1e3
        elif msg.get_srcSystem() == 1 and msg.get_type() == "RAW_IMU":
            latest = msg.time_usec / 1e6
        records.append((round(msg._timestamp * 1e6), bytes(msg.get_msgbuf())))
        clock.append(latest)
        imu.append(msg.get_type() in ("RAW_IMU", "SCALED_IMU2"))
        kinds.append(msg.get_type())
    first = [r for r, t, k in zip(records, clock, kinds, strict=True) if t <= BOOT_S and k not in left_out]
    start = clock[next(k for k, is_imu in enumerate(imu) if is_imu)]
    # the new boot's IMU streams start IMU_LATE_S after its attitudes (streams are set up one by one)
    second = [r for r, t, is_imu in zip(records, clock, imu, strict=True) if not (is_imu and t < start + IMU_LATE_S)]
    shift = first[-1][0] - records[0][0] + 1_000_000
    with open(out, "wb") as f:
        for usec, packet in first + [(usec + shift, packet) for usec, packet in second]:
            f.write(struct.pack(">Q", usec) + packet)
    return out


def slerp_errors(est: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Estimator (N×4 t, roll, pitch, yaw rad, t increasing) − reference (M×4) at each reference
    time within the estimator's span, Z-Y-X, degrees wrapped to ±180: M'×3."""
    inside = ref[(ref[:, 0] >= est[0, 0]) & (ref[:, 0] <= est[-1, 0])]
    rotations = Rotation.from_euler("ZYX", est[:, [3, 2, 1]])
    yaw, pitch, roll = Slerp(est[:, 0], rotations)(inside[:, 0]).as_euler("ZYX").T
    diff = np.degrees(np.column_stack([roll, pitch, yaw]) - inside[:, 1:4])
    return (diff + 180.0) % 360.0 - 180.0


def split_boots(rows: np.ndarray) -> list[np.ndarray]:
    """Rows (in the order made) cut where their clock goes back by more than a second."""
    return np.split(rows, np.flatnonzero(np.diff(rows[:, 0]) < -1.0) + 1)


def expected_errors(points: dict[str, np.ndarray], name: str, reference: str) -> np.ndarray:
    """Every boot's references against the same boot's outputs of the estimator."""
    est, ref = split_boots(points[name]), split_boots(points[reference])
    assert len(est) == len(ref) == 2
    return np.concatenate([slerp_errors(e, r) for e, r in zip(est, ref, strict=True)])


@pytest.fixture(scope="module")
def rebooted(logs_dir, tmp_path_factory):
    """The rebooted hop replayed through the pipeline: (path, points per source, pipeline)."""
    path = rebooted_hop(logs_dir, tmp_path_factory.mktemp("reboot") / "rebooted-hop.tlog")
    source = open_source(path)
    points: dict[str, list] = {}

    def keep(batch):
        for p in batch:
            points.setdefault(p.source, []).append((p.t, p.roll, p.pitch, p.yaw))

    pipeline = source.replay(source.new_pipeline(NAMES), keep)
    return path, {s: np.array(rows) for s, rows in points.items()}, pipeline


def test_the_live_comparison_starts_a_new_boot_clean(rebooted):
    """The new boot's first AHRS2 and ATTITUDE (5.7 s on its clock) were scored against the old
    boot's estimates at 5.7 s, still in the comparison's history: one reference too many per
    source and reboot, in the live figures, `gcs replay` and `gcs batch`."""
    _, points, pipeline = rebooted
    for name in NAMES:
        summary = pipeline.comparisons[name].summary()["references"]
        for reference in REFERENCES:
            expected = expected_errors(points, name, reference)
            session = summary[reference]["session"]
            assert session["n"] == len(expected), (name, reference)
            rms = np.sqrt(np.mean(expected**2, axis=0))
            np.testing.assert_allclose(session["rms"], rms, atol=1e-5, err_msg=f"{name} {reference}")
            worst = np.max(np.abs(expected), axis=0)
            np.testing.assert_allclose(session["max"], worst, atol=1e-5, err_msg=f"{name} {reference}")


def test_the_readable_comparison_starts_a_new_boot_clean_too(rebooted):
    """gcs.core.comparison.Comparison, the compiled one's readable reference, per sample."""
    path, points, _ = rebooted
    source = open_source(path)
    preset, gains = source.estimator_config("dcm")
    summary = compare_stream(source.inputs(), registry.create("dcm", preset, **gains)).summary()
    for reference in REFERENCES:
        expected = expected_errors(points, "dcm", reference)
        session = summary["references"][reference]["session"]
        assert session["n"] == len(expected), reference
        np.testing.assert_allclose(session["rms"], np.sqrt(np.mean(expected**2, axis=0)), atol=1e-5, err_msg=reference)


def test_what_if_replay_fast_and_the_sweep_score_the_reboot_as_the_pipeline(rebooted):
    """Whole runs (what-if's old row, `gcs replay --fast`, a sweep's score): the same figures."""
    path, points, pipeline = rebooted
    rows, _ = whole_table(open_source(path), NAMES, {})
    fast = {(r["estimator"], r["reference"]): r for r in rows}
    for name in NAMES:
        errors = run_estimator(open_source(path), name, {}).errors
        for reference in REFERENCES:
            expected = expected_errors(points, name, reference)
            rms, worst = np.sqrt(np.mean(expected**2, axis=0)), np.max(np.abs(expected), axis=0)
            np.testing.assert_allclose(errors[reference]["rms"], rms, atol=1e-5, err_msg=f"{name} {reference}")
            np.testing.assert_allclose(errors[reference]["max"], worst, atol=1e-5, err_msg=f"{name} {reference}")
            assert fast[name, reference]["n"] == len(expected), (name, reference)
            np.testing.assert_allclose(fast[name, reference]["rms_deg"], rms, atol=1e-5, err_msg=f"{name} {reference}")
        (score,) = score_flight(str(path), name, "truth", [{}]).scores
        truth = expected_errors(points, name, "truth")
        assert score == pytest.approx(math.sqrt(np.mean(truth**2)), abs=1e-5)  # the RMS of the axes' RMS


def test_a_reference_that_starts_in_the_second_boot_is_scored_against_the_second_boot(logs_dir, tmp_path, monkeypatch):
    """No SIMSTATE in the first boot (a simulator attached after the reboot): the whole-run
    errors of a session or log (`gcs report`'s error plot, `errors()`, the .mat export) paired
    the boots by position, the estimator's first boot with truth's only one, a boot's length
    apart; the live comparison scored truth against the second boot alone."""
    path = rebooted_hop(logs_dir, tmp_path / "late-truth.tlog", left_out=("SIMSTATE",))
    source = open_source(path)
    points: dict[str, list] = {}
    pipeline = source.replay(
        source.new_pipeline(NAMES),
        lambda batch: [points.setdefault(p.source, []).append((p.t, p.roll, p.pitch, p.yaw)) for p in batch],
    )
    est = split_boots(np.array(points["dcm"]))
    expected = slerp_errors(est[1], np.array(points["truth"]))  # truth: the second boot's alone
    contents = open_contents(path)
    errors = contents.errors_of("dcm", "truth")
    assert len(errors) == len(expected) == pipeline.comparisons["dcm"].summary()["references"]["truth"]["session"]["n"]
    np.testing.assert_allclose(errors[:, 1:], expected, atol=1e-5)
    row = next(r for r in contents.errors().to_pylist() if (r["estimator"], r["reference"]) == ("dcm", "truth"))
    assert row["n"] == len(expected)
    # the report's error plot: dcm − truth drawn where truth was, against the second boot
    lines = []
    plot = matplotlib.axes.Axes.plot

    def recording_plot(self, *args, **kwargs):
        lines.append(np.asarray(args[1], float))
        return plot(self, *args, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "plot", recording_plot)
    series, _ = report.collect(open_source(path), estimators=["dcm"])
    report.plot_errors(series, ["dcm"], "truth")
    assert len(lines) == 3  # roll, pitch and yaw
    for k, drawn in enumerate(lines):
        np.testing.assert_allclose(drawn[np.isfinite(drawn)], expected[:, k], atol=1e-5, err_msg=f"axis {k}")


def test_the_mcap_export_lays_the_new_boot_after_the_old(rebooted, tmp_path):
    """MCAP readers (Foxglove, PlotJuggler) order messages by log_time, which was the vehicle clock:
    the new boot's samples lay over the old boot's first 19 s, each topic's line zigzagging between
    the two, and the file's log times went back at the reboot. The new boot now follows the old one,
    1 s after its last sample, on log_time; every message keeps its own clock's t."""
    path, points, _ = rebooted
    out = tmp_path / "rebooted.mcap"
    assert main(["export", str(path), "--format", "mcap", "--out", str(out)]) == 0
    boots = [split_boots(points[source]) for source in (*NAMES, *REFERENCES)]  # in both boots
    end = max(b[0][-1, 0] for b in boots)
    shift = end + 1.0 - min(b[1][0, 0] for b in boots)
    log_times, topics = [], {}
    with open(out, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            log_times.append(message.log_time)
            if channel.topic.startswith(("/attitude/", "/imu/")):
                t = json.loads(message.data)["t"]
                topics.setdefault(channel.topic, []).append((t, message.log_time / 1e9 - t))
    assert log_times == sorted(log_times)
    both = [f"/attitude/{source}" for source in (*NAMES, *REFERENCES)] + ["/imu/RAW_IMU"]
    for topic in both:
        t, offset = np.array(topics[topic]).T
        (cut,) = np.flatnonzero(np.diff(t) < -1.0) + 1  # one reboot, no back and forth
        np.testing.assert_allclose(offset[:cut], 0.0, atol=1e-6, err_msg=topic)
        np.testing.assert_allclose(offset[cut:], shift, atol=1e-6, err_msg=topic)


def test_a_protocol_run_after_a_reboot_is_scored_with_that_boots_samples(rebooted, tmp_path, monkeypatch):
    """A session whose vehicle rebooted, then ran a protocol step (hold 6.0-6.6 s on the new boot's
    clock, where the new boot has attitudes but no IMU yet, so no estimate): its tables took every
    boot's rows and searched them as if in time order, and scored dcm with the first boot's
    outputs at those clock readings; the step now holds the run's boot's samples alone."""
    path, points, _ = rebooted
    folder = tmp_path / "session"
    folder.mkdir()
    shutil.copy(path, folder / "telemetry.tlog")
    (folder / "meta.json").write_text("{}")
    conn = mavutil.mavlink_connection(str(path))
    latest = 0.0
    while (msg := conn.recv_msg()) is not None:  # the record time of the new boot's first ATTITUDE
        if msg.get_type() == "ATTITUDE":
            if msg.time_boot_ms / 1e3 < latest - 1.0:
                break
            latest = msg.time_boot_ms / 1e3
    started = msg._timestamp + 0.1
    step = {"axis": "roll", "target_deg": 5.0, "hold_s": 0.5, "tolerance_deg": 2.0}
    window = {"index": 0, "attempt": 1, "t_start": 5.8, "t_hold_start": 6.0, "t_hold_end": 6.6}
    events = [
        {"kind": "protocol", "action": "start", "wall_time": started, "protocol": {"name": "p", "steps": [step]}},
        {"kind": "protocol", "action": "hold", "wall_time": started + 1.0, **window},
    ]
    (folder / "events.jsonl").write_text("".join(json.dumps(e) + "\n" for e in events))
    tables = session_tables(open_contents(folder))
    rows = {m.source: m for m in tables.steps}
    assert "dcm" not in rows  # no estimate in the new boot's hold window
    onboard = split_boots(points["onboard"])[1]
    hold = onboard[(onboard[:, 0] >= 6.0) & (onboard[:, 0] <= 6.6)]
    assert rows["onboard"].n_hold == len(hold) > 10
    error = np.abs(np.degrees(hold[:, 1]) - 5.0)
    assert rows["onboard"].abs_err_hold_deg == pytest.approx(np.mean(error), abs=1e-9)
    # the HTML report's plot of the hold: the same boot's samples (it drew dcm's from the first boot)
    drawn: dict[str, np.ndarray] = {}
    plot = matplotlib.axes.Axes.plot

    def recording_plot(self, *args, **kwargs):
        if kwargs.get("label"):
            drawn[kwargs["label"]] = np.asarray(args[0], float)
        return plot(self, *args, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "plot", recording_plot)
    monkeypatch.setattr(report, "plot_errors", lambda *_: "")  # the error figure draws its own lines
    monkeypatch.setattr(report, "attitude_figure", lambda *_: matplotlib.figure.Figure())
    report.write_report(str(folder), str(tmp_path / "report.html"), estimators=NAMES)
    run = onboard[(onboard[:, 0] >= 5.8) & (onboard[:, 0] <= 6.6), 0]
    np.testing.assert_array_equal(drawn["onboard"][np.isfinite(drawn["onboard"])], run)
    assert not np.isfinite(drawn["dcm"]).any()


def test_the_mat_export_says_which_boot_each_row_belongs_to(rebooted, tmp_path):
    """Each source's `t` (and its errors') starts again at the reboot; a `boot` column (1, 2)
    tells the boots apart, where plotting `t` drew a line back from one into the next."""
    path, points, _ = rebooted
    out = tmp_path / "rebooted.mat"
    assert main(["export", str(path), "--format", "mat", "--out", str(out)]) == 0
    mat = scipy.io.loadmat(out, simplify_cells=True)
    for source in (*NAMES, *REFERENCES):
        first, second = split_boots(points[source])
        struct = mat[source]
        assert struct["boot"].tolist() == [1] * len(first) + [2] * len(second), source
        np.testing.assert_array_equal(struct["t"], np.concatenate([np.sort(first[:, 0]), np.sort(second[:, 0])]))
    for reference in REFERENCES:
        errors = mat["dcm"]["errors"][reference]
        est, ref = split_boots(points["dcm"]), split_boots(points[reference])
        counts = [len(slerp_errors(e, r)) for e, r in zip(est, ref, strict=True)]
        assert errors["boot"].tolist() == [1] * counts[0] + [2] * counts[1], reference


def test_a_flights_imu_rate_counts_each_boot_over_its_own_span(rebooted):
    """`gcs batch`'s summary (imu_rate_hz) took the first IMU sample to the last across the reboot:
    the last boot's span alone, for both boots' samples."""
    path, _, _ = rebooted
    t = open_source(path).table.imu[:, 0]
    first, second = np.split(t, np.flatnonzero(np.diff(t) < -1.0) + 1)
    expected = (len(t) - 2) / (first[-1] - first[0] + second[-1] - second[0])
    assert facts(open_source(path)).imu_rate_hz == pytest.approx(expected, rel=1e-12)
    assert 20.0 < expected < 30.0  # the hop's RAW_IMU at about 25 Hz


def test_the_notebook_api_says_which_boot_each_row_belongs_to(rebooted):
    """`gcs.open_session(...).source(name)` of a log (no wall time to tell the boots apart by): its
    t starts again at the reboot; a boot column (1, 2) says where."""
    path, points, _ = rebooted
    session = gcs.open_session(path)
    for source in (*NAMES, *REFERENCES):
        first, second = split_boots(points[source])
        table = session.source(source)
        assert table["boot"].to_pylist() == [1] * len(first) + [2] * len(second), source
        assert table["t"].to_pylist() == [*np.sort(first[:, 0]), *np.sort(second[:, 0])], source


def stepped_hop(logs_dir, out):
    """The hop's records while its clock is at most 40 s, then again from 39.5 s: its clock steps
    back 0.5 s, less than a reboot (a log's time glitch)."""
    conn = mavutil.mavlink_connection(str(logs_dir / "arducopter-sitl-hop.tlog"), robust_parsing=True)
    records, clock, latest = [], [], 0.0
    while (msg := conn.recv_msg()) is not None:
        if msg.get_type() == "BAD_DATA":
            continue
        if msg.get_srcSystem() == 1 and hasattr(msg, "time_boot_ms"):
            latest = msg.time_boot_ms / 1e3
        records.append((round(msg._timestamp * 1e6), bytes(msg.get_msgbuf())))
        clock.append(latest)
    first = [r for r, t in zip(records, clock, strict=True) if t <= 40.0]
    second = [r for r, t in zip(records, clock, strict=True) if t >= 39.5]
    shift = first[-1][0] - second[0][0] + 20_000
    out.write_bytes(
        b"".join(struct.pack(">Q", usec) + packet for usec, packet in first + [(u + shift, p) for u, p in second])
    )
    return out


def test_a_clock_step_under_a_second_is_scored_alike_by_replay_fast_what_if_and_sweep(logs_dir, tmp_path):
    """The VTOL tlog's IMU clock steps back 1.0001 s, just over REBOOT_CLOCK_JUMP; here the hop's
    clock steps back 0.5 s (its records to 40 s, then again from 39.5 s), less than a reboot: the
    pipeline restarts its comparison there, and `--fast`, what-if and a sweep's score give its table."""
    path = stepped_hop(logs_dir, tmp_path / "stepped.tlog")
    source = open_source(path)
    t = source.table.imu[:, 0]
    assert -1.0 < np.diff(t).min() < -0.4  # one step back, under a second
    paced = {r["reference"]: r for r in session_table(source.replay(source.new_pipeline(["dcm"])))}
    fast = {r["reference"]: r for r in whole_table(source, ["dcm"], {})[0]}
    errors = run_estimator(source, "dcm", {}).errors
    assert set(paced) == set(fast) == set(errors) >= set(REFERENCES)
    for ref, row in paced.items():
        assert fast[ref]["n"] == row["n"], ref
        for got in (fast[ref]["rms_deg"], errors[ref]["rms"]):
            assert got == pytest.approx(row["rms_deg"], rel=1e-9, abs=1e-12), ref
        assert errors[ref]["max"] == pytest.approx(row["max_deg"], rel=1e-9, abs=1e-12), ref
    (score,) = score_flight(str(path), "dcm", "truth", [{}]).scores
    assert score == pytest.approx(math.sqrt(sum(v * v for v in paced["truth"]["rms_deg"]) / 3), rel=1e-9)


def test_the_what_if_chart_goes_forward_past_a_clock_step(logs_dir, tmp_path):
    """The what-if chart (uPlot wants its x ascending) laid only a reboot's boots one after the
    other: past the hop's 0.5 s step its x went back and the lines were drawn back in time. What
    follows the step is now laid after it, the lines broken there, as after a reboot."""
    path = stepped_hop(logs_dir, tmp_path / "stepped.tlog")
    view = what_if(open_source(path), "dcm", {"kp_rp": 0.5}).view()
    t = np.array(view.t, dtype=float)
    assert np.all(np.diff(t) > 0)
    (gap,) = [k for k, v in enumerate(view.old.roll) if v is None]  # the lines break once, at the step
    assert [k for k, v in enumerate(view.new.roll) if v is None] == [gap]
