"""Live estimation: the estimation pipeline on a live link's message bus."""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable

from gcs.core import comparison_compiled
from gcs.core.estimation import AttitudePoint, EstimationInput, EstimationPipeline
from gcs.core.estimators import registry, stepping
from gcs.core.estimators.stepping import ImuRow
from gcs.mavlink.sampling import INPUT_TYPES, SAMPLED_TYPES, MessageInputs
from gcs.mavlink.tlog import tlog_wall_time
from gcs.runtime import heap
from gcs.runtime.bus import Message, Subscription
from gcs.runtime.link import Link, LinkState
from gcs.runtime.signal import Signal
from gcs.runtime.snapshots import ErrorStats, EstimationSnapshot, EstimatorSnapshot, SourceAttitude, finite

#: Messages estimated per turn of the event loop at most. Behind (a flood, a starved machine), the
#: estimation takes this many, then lets the link read the socket before the next ones: the
#: backlog waits in the estimation's own bounded queue (oldest dropped and counted when full),
#: not in the kernel's buffer, where it would be lost for the recording and the outputs too. In one
#: callback a backlog held the loop for 10-50 ms under load (bench.loop_stalls).
#: About 2 ms of estimation at the live pipeline's ~100-150 µs per IMU message: at 20,000 msg/s a turn
#: brings ~50 datagrams, fewer than the link reads in one (gcs.transport.pipes.UDP_READ_BATCH).
BATCH = 16
#: Messages that arrive within a tick of the last turn that estimated are estimated together, at
#: its end: a turn per tick instead of one per datagram (each wakes the loop alone), so the
#: per-turn costs (the task's wake-up, the listeners' calls, the live hub's scheduling) are paid
#: per tick. The dashboard sets the tick to its live hub's frame interval (`pace`), so a sample
#: waits no longer than it waited for its frame: the frame goes out right after the tick's points
#: arrive. This is the tick without a dashboard (the hub's longest interval). A batch already
#: waiting (BATCH or more) is estimated at once: the estimation is behind. On a UDP link the
#: dashboard paces the reads instead (`Link.pace_reads`): each read is a turn, and no timer of the
#: estimation's own adds a wake-up of the loop to the link's.
TICK = 0.010


def warm() -> None:
    """Compile (or load from the disk cache) the estimators' kernels, their batch stepping and the
    comparison's kernels."""
    registry.warm()
    stepping.warm()
    comparison_compiled.warm()


#: An estimator's reason while the estimation loads its compiled kernels, not its IMU rate's
#: (0 Hz then: nothing is estimated yet, though the IMU arrives).
STARTING = (
    "starting: loading the compiled estimators (the first start after an install compiles them, "
    "a minute or more); the samples arriving meanwhile are estimated then"
)


def live_reason(ready: bool, stale: str | None, reason: str, rate_limit: str | None = None) -> str:
    """An estimator's reason to read unreliable: starting first, then a lost link or a silent IMU
    (its comparison's own reason, judged over the last IMU samples, no longer says anything), then
    the comparison's reason ("" when reliable; its IMU rate's, with what limits it when known)."""
    if not ready:
        return STARTING
    if stale is not None:
        return stale
    return f"{reason} ({rate_limit})" if reason and rate_limit else reason


class LiveEstimation:
    """Runs an EstimationPipeline on a live link's bus and hands every AttitudePoint to the
    listeners (dashboard streams, the session recorder).

    `messages_fed` counts the input messages (`INPUT_TYPES`) taken from the bus: the input position
    at which a gain change is recorded, so that a replay re-applies it exactly where it was applied
    live. EKF_STATUS_REPORT is taken too (`SAMPLED_TYPES`: it names ATTITUDE's reference) but not
    counted, as the replay does not count it.
    """

    def __init__(self, link: Link, pipeline: EstimationPipeline | None = None, tick: float = TICK) -> None:
        self.link = link
        self.tick: Callable[[], float] = lambda: tick
        self.pipeline = pipeline or EstimationPipeline()
        self.inputs = MessageInputs()
        self.messages_fed = 0
        #: the attitudes each drained batch of messages produced
        self.points: Signal[[list[AttitudePoint]]] = Signal()
        #: the first 3D GPS fix (ArduPilot sets COMPASS_DEC then: ask for it again)
        self.gps_locked: Signal[[]] = Signal()
        #: the declination's source or value changed: (source, rad or None)
        self.declination_changed: Signal[[str, float | None]] = Signal()
        self._sub: Subscription | None = None
        #: the compiled kernels are loaded and the estimation runs (until then what arrives waits)
        self.ready = False
        #: host monotonic s at which the last batch that gave the estimators an IMU sample arrived
        self.imu_arrived: float | None = None

    def pace(self, interval: Callable[[], float]) -> None:
        """Estimate at most once per interval() s (the live hub's frame interval, which follows
        its number of viewers) while not behind."""
        self.tick = interval

    @property
    def imu_type(self) -> str | None:
        return self.inputs.sampler.imu_type

    def stale(self, now: float) -> str | None:
        """Why the comparisons' reliability no longer holds at host time `now`, or None. It is judged
        over their last window of IMU samples, which stays as it was when the samples stop: a lost
        link, or no IMU for longer than that window, would go on reading "reliable" without this."""
        age = None if self.imu_arrived is None else now - self.imu_arrived
        silent = "no IMU yet" if age is None else f"no IMU for {age:.0f} s"
        if self.link.state == LinkState.LOST:
            return f"link lost: {silent}"
        window = self.pipeline.window
        if age is not None and age > window:
            return f"{silent}, longer than the {window:g} s window its rate is judged over"
        return None

    def snapshot(self, now: float, rate_limit: str | None = None) -> EstimationSnapshot:
        """What the station publishes of the estimation at host time `now` (monotonic s).
        `rate_limit`: what holds the raw IMU below the rate asked for, added to a too-low rate's
        reason (its advice, "request RAW_IMU at 50 Hz", reads as if nobody had)."""
        pipeline = self.pipeline
        stale = self.stale(now)
        estimators = {}
        for name, est in pipeline.estimators.items():
            summary = pipeline.comparisons[name].summary()
            errors = {
                ref: ErrorStats(
                    n=s["n"],
                    window_rms_deg=[finite(v) for v in s["window"]["rms"]],
                    window_max_deg=[finite(v) for v in s["window"]["max"]],
                    session_rms_deg=[finite(v) for v in s["session"]["rms"]],
                    session_max_deg=[finite(v) for v in s["session"]["max"]],
                )
                for ref, s in summary["references"].items()
            }
            estimators[name] = EstimatorSnapshot(
                preset=est.preset,
                gains=dict(est.gains.values),
                health={k: finite(v) if isinstance(v, float) else v for k, v in est.health().items()},
                reliable=summary["reliable"] and self.ready and stale is None,
                reason=live_reason(self.ready, stale, summary["reason"], rate_limit),
                imu_rate_hz=round(summary["imu_rate"], 2),
                lag_s=summary["lag"],
                dropped=summary["dropped"],
                errors=errors,
            )
        latest = {
            source: SourceAttitude(
                source,
                "estimator" if source in pipeline.estimators else "reference",
                p.t,
                math.degrees(p.roll),
                math.degrees(p.pitch),
                math.degrees(p.yaw),
            )
            for source, p in pipeline.latest.items()
        }
        return EstimationSnapshot(
            self.imu_type,
            pipeline.imu_samples,
            pipeline.declination,
            estimators,
            latest,
            refused_inputs=dict(pipeline.refused),
            restarts=dict(pipeline.restarts),
            restart_reasons=dict(pipeline.restart_reasons),
            declination_source=self.inputs.declination_source,
        )

    def subscribe(self) -> None:
        """Take the bus's inputs from now on, before `run` first runs (Station.launch): a fleet's new
        core is handed the messages that came with its vehicle's first heartbeat at once, and its
        recorder keeps them; subscribed only when its task ran, the estimation missed them, and the
        session's replay had samples the live run never estimated."""
        if self._sub is None:
            self._sub = self.link.bus.subscribe("estimation", types=SAMPLED_TYPES, maxlen=100_000)

    async def run(self) -> None:
        self.subscribe()
        sub = self._sub
        assert sub is not None  # (subscribe)
        try:
            # the compiled estimators load (or, the first time, compile) off the loop: what arrives
            # meanwhile waits in the subscription (and is estimated below if the station stops first)
            await asyncio.to_thread(warm)
            self.ready = True
            heap.freeze()  # the kernels' objects are here for good: no collection walks them
            loop = asyncio.get_running_loop()
            next_tick = loop.time()
            while True:
                await sub.queue.wait()
                delay = next_tick - loop.time()
                if delay > 0 and len(sub.queue) < BATCH:  # the rest of the tick's messages come too
                    await asyncio.sleep(delay)
                # a paced link's read is the tick: it brings the interval's messages at once
                next_tick = loop.time() + (0.0 if self.link.reads_paced else self.tick())
                self._feed(sub.drain(BATCH))
                if len(sub.queue):  # behind: let the link read in between (its queue takes the backlog)
                    await asyncio.sleep(0)
        except asyncio.CancelledError:
            # Stopping: what the link delivered is estimated too, so that a recording and the
            # live outputs hold the same inputs (the station stops the link first). A pipeline
            # that failed is not fed again: it would only raise again, in the station's stop.
            self._feed(sub.drain())
            raise
        finally:
            sub.close()
            self._sub = None  # stopped or failed: nothing left to catch up on
            heap.release()

    def catch_up(self) -> None:
        """Estimate now every message the link has delivered (those waiting for the next tick or
        batch): a session that stops then holds the estimates of every input its tlog holds."""
        if self._sub is not None:
            self._feed(self._sub.drain())

    def _feed(self, items: list[Message]) -> None:
        """The batch's messages → inputs, estimated together (`EstimationPipeline.feed_many`); what
        they gave before a declination signal is estimated before it goes out, as per message. An
        IMU message read from its bytes becomes its batch row directly (`MessageInputs.feed_imu`:
        no ImuSample, and no declination change to look for) wherever that gives what `feed` does."""
        points: list[AttitudePoint] = []
        inputs: list[EstimationInput | ImuRow] = []
        # per message: bound methods and the declination read once (MessageInputs' properties)
        feed_inputs, feed_imu, feed_many = self.inputs.feed, self.inputs.feed_imu, self.pipeline.feed_many
        declination = self.inputs.vehicle_declination
        imu_before = self.pipeline.imu_samples
        for item in items:
            self.messages_fed += item.type in INPUT_TYPES
            imu = item.imu
            if imu is not None and feed_imu(imu, inputs):
                continue
            had_fix, source, value = declination.gps_fix, declination.source, declination.value
            # the wall time as the recording's tlog keeps it, so a replay dates the WMM the same
            inputs += feed_inputs(item.reading, tlog_wall_time(item.wall_time))
            locked = declination.gps_fix and not had_fix
            changed = (declination.source, declination.value) != (source, value)
            if locked or changed:
                points += feed_many(inputs)
                inputs = []
            if locked:
                self.gps_locked.emit()
            if changed:
                self.declination_changed.emit(declination.source, declination.value)
        if inputs:
            points += feed_many(inputs)
        if items and self.pipeline.imu_samples > imu_before:  # to within a batch (a tick, BATCH messages)
            self.imu_arrived = items[-1].host_time
        if points:
            self.points.emit(points)
