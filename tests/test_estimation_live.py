"""Issue acceptance on the simulator, every profile, live: the estimators converge within 10 s
of vehicle time, and the live comparison numbers equal an offline recomputation from the
session recorded at the same time."""

from __future__ import annotations

import asyncio
import json
import math

import pytest
from conftest import free_port
from live import running_sim, running_station, wait_for

from gcs.core.rotation import wrap_pi
from gcs.runtime.replay import ReplaySession
from gcs.sessions.sources import open_source

ESTIMATORS = ("dcm", "kf", "ekf")


def errors_after(points, start: float, end: float) -> dict[str, tuple[float, float, float]]:
    """Largest |error| per axis (deg) of each estimator against the truth in [start, end] s,
    each truth point matched with the estimator output at the same IMU burst (nearest t)."""
    by_source: dict[str, list] = {}
    for p in points:
        by_source.setdefault(p.source, []).append(p)
    truth = [p for p in by_source["truth"] if start <= p.t <= end]
    worst = {}
    for name in ESTIMATORS:
        est = by_source[name]
        err = [0.0, 0.0, 0.0]
        for ref in truth:
            e = min(est, key=lambda p: abs(p.t - ref.t))
            for i, (a, b) in enumerate(((e.roll, ref.roll), (e.pitch, ref.pitch), (e.yaw, ref.yaw))):
                err[i] = max(err[i], abs(math.degrees(wrap_pi(a - b))))
        worst[name] = tuple(err)
    return worst


@pytest.mark.parametrize("profile", ["apm25", "pixhawk", "px4"])
def test_live_estimators_converge_and_match_offline_recomputation(profile, tmp_path):
    port = free_port()
    points = []

    async def fly():
        async with running_station(f"udpin:127.0.0.1:{port}", sessions_dir=str(tmp_path), record=True) as station:
            station.estimation.points.connect(points.extend)
            async with running_sim(f"udpout:127.0.0.1:{port}", profile=profile, script="quad", speed=2.0):
                await wait_for(lambda: points and points[-1].t > 16.0, 30, "16 s of vehicle time")
            folder = station.recorder.session.folder
        # stopped: the live estimation has consumed everything the recording holds
        return station.estimation.pipeline.summary(), folder

    live, folder = asyncio.run(fly())
    worst = errors_after(points, 10.0, 16.0)
    print(
        f"\n{profile}: max error vs truth after 10 s (roll, pitch, yaw deg):",
        {k: tuple(round(x, 2) for x in v) for k, v in worst.items()},
    )
    for name, (roll, pitch, yaw) in worst.items():
        assert roll < 3.0 and pitch < 3.0, f"{profile} {name}: roll/pitch error {roll:.2f}/{pitch:.2f} deg after 10 s"
        assert yaw < 10.0, f"{profile} {name}: yaw error {yaw:.2f} deg after 10 s"

    replay = ReplaySession(open_source(folder), speed=0)
    replay.run_to_end()
    offline = replay.pipeline.summary()
    assert live["imu_samples"] == offline["imu_samples"] > 300
    for name in ESTIMATORS:
        a = json.dumps(live["estimators"][name]["comparison"], sort_keys=True)
        b = json.dumps(offline["estimators"][name]["comparison"], sort_keys=True)
        assert a == b, f"{profile} {name}: live and offline comparison differ"
        assert "truth" in live["estimators"][name]["comparison"]["references"]
