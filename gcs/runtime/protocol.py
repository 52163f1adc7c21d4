"""A test protocol run live on the Station: one step at a time, the hold detected on the live
attitudes, every step's window recorded in the session's event log, the step scored at its end.

The attitudes of every source since the step's prompt are kept (bounded) and scored once, when
the hold completes: a few thousand samples, so the loop is not held. The session's events carry
the protocol and every window, so the report recomputes the same numbers from the recording.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Protocol as TypingProtocol

import numpy as np

from gcs.core.estimation import AttitudePoint
from gcs.core.protocol import HoldDetector, Protocol, SourceMetrics, Step, StepWindow, step_metrics
from gcs.runtime.events import EventLog
from gcs.runtime.signal import Signal
from gcs.sessions.protocol import EVENT_KIND, window_event

#: Attitudes kept per source for one step (10 min at 400 Hz): an operator who walks away does not
#: grow memory without bound, only loses the oldest part of the rise.
STEP_BUFFER = 240_000


@dataclass(frozen=True, slots=True)
class ProtocolState:
    """Where the run is, for the terminal and the dashboard."""

    protocol: str
    step: int  # 0-based index of the current step; == len(steps) when finished
    steps: int
    attempt: int
    prompt: str
    completed: int
    skipped: int
    finished: bool


class Attitudes(TypingProtocol):
    """What a run needs of the Station: its attitudes as they are produced, and its event log."""

    points: Signal[[list[AttitudePoint]]]
    events: EventLog


class LiveProtocol:
    """Runs `protocol` on a started Station's attitudes. Connect to `step_done` (the window and
    every source's metrics) and `changed` (a new prompt); `skip`, `repeat` and `finish` are
    commands on the loop."""

    def __init__(
        self, station: Attitudes, protocol: Protocol, detect_source: str | None = None, client: str = "cli"
    ) -> None:
        self.station = station
        self.protocol = protocol
        self.detect_source = detect_source or protocol.detect_source
        self.client = client
        self.index = 0
        self.attempts = [0] * len(protocol.steps)
        self.windows: list[StepWindow] = []
        self.skipped: list[int] = []
        self.results: dict[int, list[SourceMetrics]] = {}
        self.ended = False
        self.step_done: Signal[[StepWindow, list[SourceMetrics]]] = Signal()
        self.changed: Signal[[ProtocolState]] = Signal()
        self._buffers: dict[str, deque[tuple[float, float, float, float]]] = {}
        self._detector: HoldDetector | None = None
        self._t_start: float | None = None
        self._disconnect = station.points.connect(self._on_points)
        station.events.record(EVENT_KIND, client, action="start", protocol=protocol.as_dict())
        self._begin(0)

    @property
    def finished(self) -> bool:
        return self.index >= len(self.protocol.steps)

    @property
    def step(self) -> Step | None:
        return None if self.finished else self.protocol.steps[self.index]

    def state(self) -> ProtocolState:
        step = self.step
        return ProtocolState(
            self.protocol.name,
            self.index,
            len(self.protocol.steps),
            self.attempts[self.index] if step else 0,
            step.prompt if step else "protocol finished",
            len({w.index for w in self.windows}),
            len(self.skipped),
            self.finished,
        )

    def completed_results(self) -> list[SourceMetrics]:
        """Every source's figures for each completed step (its latest attempt), in step order."""
        return [m for index in sorted(self.results) for m in self.results[index]]

    # ---- commands ----------------------------------------------------------------------
    def skip(self) -> None:
        """Leave the current step without a result."""
        if self.finished or self.ended:
            return
        self.skipped.append(self.index)
        self.station.events.record(EVENT_KIND, self.client, action="skip", index=self.index)
        self._begin(self.index + 1)

    def repeat(self) -> None:
        """Go back to the previous step and do it again; its new window replaces the old one."""
        if self.index == 0 or self.ended:
            return
        index = self.index - 1
        self.station.events.record(EVENT_KIND, self.client, action="repeat", index=index)
        self._begin(index)

    def finish(self) -> None:
        """End the run (all steps done, or given up) and stop listening; once."""
        if self.ended:
            return
        self.ended = True
        self._detector = None
        self._disconnect()
        self.station.events.record(
            EVENT_KIND,
            self.client,
            action="end",
            completed=len({w.index for w in self.windows}),
            skipped=len(self.skipped),
            steps=len(self.protocol.steps),
        )

    # ---- the run -------------------------------------------------------------------------
    def _begin(self, index: int) -> None:
        self.index = index
        self._buffers = {}
        self._t_start = None
        step = self.step
        self._detector = None if step is None else HoldDetector(step)
        if step is not None:
            self.attempts[index] += 1
            self.station.events.record(
                EVENT_KIND, self.client, action="prompt", index=index, attempt=self.attempts[index], prompt=step.prompt
            )
        else:
            self.finish()
        self.changed.emit(self.state())

    def _on_points(self, points: list[AttitudePoint]) -> None:
        detector = self._detector
        if detector is None:
            return
        held = None
        for p in points:
            buffer = self._buffers.get(p.source)
            if buffer is None:
                buffer = self._buffers[p.source] = deque(maxlen=STEP_BUFFER)
            buffer.append((p.t, p.roll, p.pitch, p.yaw))
            if p.source == self.detect_source:
                if self._t_start is None:
                    self._t_start = p.t
                held = held or detector.feed(p.t, (p.roll, p.pitch, p.yaw))
        if held is not None and self._t_start is not None:
            self._complete(float(held[0]), float(held[1]))

    def _complete(self, t_hold_start: float, t_hold_end: float) -> None:
        assert self._t_start is not None
        window = StepWindow(self.index, self.attempts[self.index], self._t_start, t_hold_start, t_hold_end)
        self.windows.append(window)
        self.station.events.record(EVENT_KIND, self.client, **window_event(window))
        metrics = []
        for source, buffer in self._buffers.items():
            series = np.array(buffer, dtype=np.float64)
            m = step_metrics(self.protocol, window, source, series[np.argsort(series[:, 0], kind="stable")])
            if m is not None:
                metrics.append(m)
        self.results[window.index] = metrics
        self.step_done.emit(window, metrics)
        self._begin(self.index + 1)
