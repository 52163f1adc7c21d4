"""One vehicle's message stream → every estimator → comparison with the references.

`EstimationPipeline` is synchronous and deterministic: the live ground station and the
replay of a recording feed it the same messages in the same order and get the same numbers.
`LiveEstimation` runs it on the message bus of a live link.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Iterable

from gcs.estimators import registry
from gcs.estimators.base import AttitudeEstimator
from gcs.estimators.compare import Comparison
from gcs.link.dialect import mavlink
from gcs.rotation import quat_to_euler
from gcs.sensors import IMU_TYPES, AttitudeSample, GpsSample, ImuSample, MessageSampler

#: Vehicle parameters holding the magnetic declination, and their unit → rad conversion.
DECLINATION_PARAMS: dict[str, Callable[[float], float]] = {
    "COMPASS_DEC": float,  # ArduPilot: radians
    "EKF2_MAG_DECL": math.radians,  # PX4: degrees
}

#: Every message type the pipeline reads.
INPUT_TYPES = frozenset({*IMU_TYPES, "GPS_RAW_INT", "ATTITUDE", "AHRS2", "SIMSTATE", "PARAM_VALUE"})


@dataclass(frozen=True, slots=True)
class AttitudePoint:
    """One attitude of one source at a vehicle time: a reference ("onboard", "ahrs2",
    "truth") or an estimator (its name). Angles in rad, Z-Y-X."""

    t: float
    source: str
    roll: float
    pitch: float
    yaw: float


class EstimationPipeline:
    def __init__(
        self,
        estimators: dict[str, AttitudeEstimator] | None = None,
        imu_type: str | None = None,
        system: int | None = None,
        window: float = 10.0,
    ) -> None:
        self.sampler = MessageSampler(imu_type, system)
        self.estimators = estimators if estimators is not None else {n: registry.create(n) for n in registry.names()}
        self.comparisons = {name: Comparison(window=window) for name in self.estimators}
        self.latest: dict[str, AttitudePoint] = {}
        self.imu_samples = 0
        self.messages_fed = 0  # the input position: where a recorded gain change is re-applied on replay
        self.declination: float | None = None

    def feed(self, msg) -> list[AttitudePoint]:
        """Fuse one message; returns the attitudes it produced (none, one reference, or one per
        valid estimator after an IMU sample)."""
        self.messages_fed += 1
        if msg.get_type() == "PARAM_VALUE":
            self._maybe_declination(msg)
            return []
        sample = self.sampler.feed(msg)
        return [] if sample is None else self.feed_sample(sample)

    def feed_sample(self, sample: ImuSample | GpsSample | AttitudeSample) -> list[AttitudePoint]:
        """Fuse one sample from any source (a log reader's stream: DataFlash, ULog, CSV)."""
        if isinstance(sample, ImuSample):
            return self._imu(sample)
        if isinstance(sample, GpsSample):
            for est in self.estimators.values():
                est.update_gps(sample)
            return []
        return [self._reference(sample)]

    def feed_all(self, messages: Iterable) -> None:
        for msg in messages:
            self.feed(msg)

    def _imu(self, sample: ImuSample) -> list[AttitudePoint]:
        self.imu_samples += 1
        points = []
        for name, est in self.estimators.items():
            valid = est.update_imu(sample)
            q = est.quaternion
            self.comparisons[name].add_estimate(sample.t, q)
            if valid:
                point = AttitudePoint(sample.t, name, *quat_to_euler(q))
                self.latest[name] = point
                points.append(point)
        return points

    def _reference(self, ref: AttitudeSample) -> AttitudePoint:
        for comparison in self.comparisons.values():
            comparison.add_reference(ref)
        point = AttitudePoint(ref.t, ref.source, ref.roll, ref.pitch, ref.yaw)
        self.latest[ref.source] = point
        return point

    def _maybe_declination(self, msg) -> None:
        name = msg.param_id.rstrip("\x00") if isinstance(msg.param_id, str) else msg.param_id.decode().rstrip("\x00")
        to_rad = DECLINATION_PARAMS.get(name)
        if to_rad is None:
            return
        value = to_rad(msg.param_value)
        if -math.pi <= value <= math.pi and value != self.declination:
            self.declination = value
            for est in self.estimators.values():
                est.set_gain("declination", value)

    def set_gain(self, estimator: str, name: str, value: float) -> tuple[float, float]:
        """Change one gain of one estimator now; GainError/KeyError name what is wrong."""
        if estimator not in self.estimators:
            raise KeyError(f"unknown estimator {estimator!r}; running: {', '.join(self.estimators)}")
        return self.estimators[estimator].set_gain(name, value)

    def summary(self) -> dict:
        """Per estimator: preset, gains, health and the comparison; latest attitude per source."""
        return {
            "imu_type": self.sampler.imu_type,
            "imu_samples": self.imu_samples,
            "declination_rad": self.declination,
            "estimators": {
                name: {
                    "preset": est.preset,
                    "gains": dict(est.gains.values),
                    "health": est.health(),
                    "comparison": self.comparisons[name].summary(),
                }
                for name, est in self.estimators.items()
            },
            "latest": {
                source: {"t": p.t, "roll_deg": math.degrees(p.roll), "pitch_deg": math.degrees(p.pitch),
                         "yaw_deg": math.degrees(p.yaw)}
                for source, p in self.latest.items()
            },
        }


class LiveEstimation:
    """Runs an EstimationPipeline on a live link's bus and hands every AttitudePoint to the
    listeners (dashboard streams, the session recorder). Asks the vehicle for its declination
    parameter on connect."""

    def __init__(self, link, pipeline: EstimationPipeline | None = None) -> None:
        self.link = link
        self.pipeline = pipeline or EstimationPipeline()
        self._listeners: list[Callable[[list[AttitudePoint]], None]] = []

    def add_listener(self, callback: Callable[[list[AttitudePoint]], None]) -> None:
        self._listeners.append(callback)

    async def run(self) -> None:
        sub = self.link.bus.subscribe("estimation", types=INPUT_TYPES, maxlen=100_000)
        self.link.add_state_listener(lambda old, new: new == "connected" and self._ask_declination())
        try:
            while True:
                items = [await sub.get(), *sub.drain()]
                points: list[AttitudePoint] = []
                for item in items:
                    points += self.pipeline.feed(item.msg)
                if points:
                    for callback in self._listeners:
                        callback(points)
        finally:
            sub.close()

    def _ask_declination(self) -> None:
        for name in DECLINATION_PARAMS:
            self.link.send(mavlink.MAVLink_param_request_read_message(
                self.link.target_system or 1, self.link.target_component or 1, name.encode(), -1))
