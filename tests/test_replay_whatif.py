"""What-if: the original run reproduces the replay's output, the new gains change it, a
workbench re-runs nothing it has run and keeps bounded caches, and bad gains are refused before
any work."""

from __future__ import annotations

import numpy as np
import pytest

from gcs.core.gains import GainError
from gcs.runtime.replay import ReplaySession
from gcs.sessions.sources import open_source
from gcs.sessions.whatif import what_if
from gcs.sessions.workbench import Workbench


@pytest.fixture(scope="module")
def hop(logs_dir):
    return open_source(logs_dir / "arducopter-sitl-hop.BIN")


def test_old_run_is_the_replay_and_new_gains_change_it(hop):
    session = ReplaySession(hop, speed=0, estimators=["dcm"])
    points = []
    session.points.connect(lambda ps: points.extend(p for p in ps if p.source == "dcm"))
    session.run_to_end()
    result = what_if(hop, "dcm", {"kp_rp": 1.0})
    assert np.array_equal(result.old.t, [p.t for p in points])
    assert np.allclose(result.old.euler, [(p.roll, p.pitch, p.yaw) for p in points], atol=1e-12)
    assert result.new.gains["kp_rp"] == 1.0 and result.old.gains["kp_rp"] != 1.0
    assert not np.allclose(result.new.euler, result.old.euler)
    rows = {row.reference: row for row in result.table()}
    assert set(rows) == {"onboard", "ahrs2", "truth"}
    assert rows["truth"].new_rms != rows["truth"].old_rms
    view = result.view(max_points=500)
    assert len(view.t) == len(view.new.roll) <= 500
    step = -(-len(result.new.t) // 500)
    np.testing.assert_allclose(view.new.roll, np.degrees(result.new.euler[::step, 0]))


def test_workbench_decodes_and_runs_once_within_bounds(logs_dir, tmp_path):
    bench = Workbench(sources=1, runs=2)
    path = logs_dir / "arducopter-sitl-hop.BIN"
    source = bench.source(path)
    assert bench.source(path).table is source.table  # same decode, not a second one
    first = what_if(source, "dcm", {"kp_rp": 0.3}, bench.run)
    again = what_if(bench.source(path), "dcm", {"kp_rp": 0.3}, bench.run)
    assert again.old is first.old and again.new is first.new
    assert bench.cache_info() == (1, 2)
    what_if(source, "dcm", {"kp_rp": 0.5}, bench.run)
    assert bench.cache_info() == (1, 2)  # the oldest run went, not memory
    copy = tmp_path / "copy.BIN"
    copy.write_bytes(path.read_bytes())
    assert bench.source(copy).table is not source.table and bench.cache_info()[0] == 1
    copy.write_bytes(path.read_bytes()[:100_000])  # changed file: decoded again
    assert len(bench.source(copy).table) < len(source.table)


def test_bad_gain_is_refused(hop):
    with pytest.raises(GainError, match="kp_rp"):
        what_if(hop, "dcm", {"kp_rp": -1})
    with pytest.raises(KeyError, match="nope"):
        what_if(hop, "nope", {})
