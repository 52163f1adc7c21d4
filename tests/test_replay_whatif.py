"""What-if: the original run reproduces the replay's output, the new gains change it, only the
changed estimator is re-run, and bad gains are refused before any work."""

from __future__ import annotations

import time

import numpy as np
import pytest

from gcs.core.gains import GainError
from gcs.runtime.replay import ReplaySession
from gcs.sessions.sources import open_source
from gcs.sessions.whatif import what_if


@pytest.fixture(scope="module")
def hop(logs_dir):
    return open_source(logs_dir / "arducopter-sitl-hop.BIN")


def test_old_run_is_the_replay_and_new_gains_change_it(hop):
    session = ReplaySession(hop, speed=0, estimators=["dcm"])
    points = []
    session.add_listener(lambda ps: points.extend(p for p in ps if p.source == "dcm"))
    session.run_to_end()
    result = what_if(hop, "dcm", {"kp_rp": 1.0})
    assert np.array_equal(result.old.t, [p.t for p in points])
    assert np.allclose(result.old.euler, [(p.roll, p.pitch, p.yaw) for p in points], atol=1e-12)
    assert result.new.gains["kp_rp"] == 1.0 and result.old.gains["kp_rp"] != 1.0
    assert not np.allclose(result.new.euler, result.old.euler)
    rows = {row["reference"]: row for row in result.table()}
    assert set(rows) == {"onboard", "ahrs2", "truth"}
    assert rows["truth"]["new_rms"] != rows["truth"]["old_rms"]
    data = result.as_dict(max_points=500)
    assert len(data["t"]) == len(data["new"]["roll"]) <= 500


def test_rerun_is_cached_and_fast(hop):
    what_if(hop, "dcm", {"kp_rp": 0.3})
    started = time.perf_counter()
    again = what_if(hop, "dcm", {"kp_rp": 0.3})
    assert time.perf_counter() - started < 0.05 and again.elapsed_s < 0.05


def test_bad_gain_is_refused(hop):
    with pytest.raises(GainError, match="kp_rp"):
        what_if(hop, "dcm", {"kp_rp": -1})
    with pytest.raises(KeyError, match="nope"):
        what_if(hop, "nope", {})
