"""The live run's bookkeeping (gcs.runtime.protocol.LiveProtocol) on a real Signal and EventLog,
fed attitudes by hand: a hold, a repeat that replaces it, a skip, and the events it records."""

from __future__ import annotations

import math

import pytest

from gcs.core.estimation import AttitudePoint
from gcs.core.protocol import Protocol, Step
from gcs.runtime.events import EventLog
from gcs.runtime.protocol import LiveProtocol
from gcs.runtime.signal import Signal


class Attitudes:
    """The two things a run takes from the Station."""

    def __init__(self) -> None:
        self.points: Signal[[list[AttitudePoint]]] = Signal()
        self.events = EventLog()


def hold(station: Attitudes, t0: float, roll_deg: float, offset_deg: float, seconds: float = 1.5) -> float:
    """Feed truth at roll_deg and an estimator offset by offset_deg, at 50 Hz, from t0; returns the end."""
    t = t0
    while t < t0 + seconds:
        station.points.emit(
            [
                AttitudePoint(t, "truth", math.radians(roll_deg), 0.0, 0.0),
                AttitudePoint(t, "est", math.radians(roll_deg + offset_deg), 0.0, 0.0),
            ]
        )
        t = round(t + 0.02, 6)
    return t


def test_repeat_replaces_a_step_and_skip_ends_the_run():
    station = Attitudes()
    protocol = Protocol("p", (Step("roll", -30.0, 1.0, 2.0), Step("roll", 45.0, 1.0, 2.0)), detect_source="truth")
    live = LiveProtocol(station, protocol)
    done = []
    live.step_done.connect(lambda window, metrics: done.append((window, metrics)))
    t = hold(station, 0.0, 0.0, 0.0)  # level: nothing held
    assert live.index == 0 and not done
    t = hold(station, t, -30.0, 0.6)
    assert live.index == 1 and done[0][0].attempt == 1
    first = {m.source: m for m in done[0][1]}
    assert first["est"].mre_last_pct == pytest.approx(2.0) and first["truth"].mre_last_pct == 0.0  # 0.6 / 30
    live.repeat()
    assert live.index == 0 and live.state().attempt == 2
    hold(station, t, -30.0, 0.3)
    assert live.index == 1 and [w.attempt for w in live.windows] == [1, 2]
    (again,) = [m for m in live.completed_results() if m.source == "est"]
    assert again.mre_last_pct == pytest.approx(1.0)  # the repeat's figure replaced the first attempt's
    live.skip()
    assert live.finished and live.ended and live.state().skipped == 1
    hold(station, t + 10, 45.0, 0.0)  # after the end nothing is listened to
    assert len(live.windows) == 2
    actions = [e.data["action"] for e in station.events.recent if e.kind == "protocol"]
    assert actions == ["start", "prompt", "hold", "prompt", "repeat", "prompt", "hold", "prompt", "skip", "end"]
