"""The /ws/live wire format (gcs.server.wire): the bytes of a frame laid out by hand here, a real
LiveHub batching every frame queued for a client into one binary message, and a gain change in
order with the points around it."""

from __future__ import annotations

import asyncio
import math
import struct

import numpy as np
import pytest

from gcs.core.estimation import AttitudePoint
from gcs.server import wire
from gcs.server.live import LiveHub


def test_points_frame_bytes_as_documented():
    frame = wire.points_frame(7, 12.5, {"dcm": [[1.0000004, 2.0], [10.0, -10.0], [1.5, 2.5], [179.0, -179.0]]})
    header = struct.pack("<IBBHIId", len(frame), 1, 1, 1, 7, 0, 12.5)
    series = struct.pack("<HHI", 3, 0, 2) + b"dcm\0\0\0\0\0"
    # times at µs (as GET /api/history), angles as float32, padded to 8 bytes
    arrays = struct.pack("<2d", 1.0, 2.0) + struct.pack("<6f", 10.0, -10.0, 1.5, 2.5, 179.0, -179.0)
    assert frame == header + series + arrays
    assert len(frame) % 8 == 0


def test_odd_lengths_stay_aligned_and_decode():
    points = {
        "onboard": [[0.1, 0.2, 0.3], [1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]],
        "kf": [[0.15], [-1.0], [-2.0], [-3.0]],
    }
    frame = wire.points_frame(1, 0.0, points)
    assert len(frame) % 8 == 0
    (decoded,) = wire.decode(frame)
    assert list(decoded.points) == ["onboard", "kf"]
    for source, cols in points.items():
        for got, sent in zip(decoded.points[source], cols, strict=True):
            assert got == pytest.approx(sent, abs=1e-6)


def test_bad_frames_are_refused():
    frame = wire.points_frame(1, 0.0, {"onboard": [[0.1], [1.0], [2.0], [3.0]]})
    with pytest.raises(ValueError, match="bad frame"):
        list(wire.decode(frame[:-8]))  # cut short
    with pytest.raises(ValueError, match="bad frame"):
        list(wire.decode(frame[:5] + b"\x02" + frame[6:]))  # another version
    nan = wire.points_frame(1, 0.0, {"onboard": [[0.1], [math.nan], [2.0], [3.0]]})
    with pytest.raises(ValueError, match="non-finite"):
        list(wire.decode(nan))


def test_a_client_gets_every_queued_frame_in_one_message_in_order():
    async def flushed(hub: LiveHub, frames: int) -> None:
        while hub.frames_out < frames:  # the flush is a callback of the loop: give it its turn
            await asyncio.sleep(0)

    async def run() -> tuple[bytes, int, int]:
        hub = LiveHub(seconds=10, frame_interval=0.0)
        feed = hub.connect("test")
        hub.on_points([AttitudePoint(1.0, "onboard", 0.1, 0.2, 0.3)])
        await asyncio.wait_for(flushed(hub, 1), 5)
        hub.broadcast({"type": "gain", "estimator": "dcm", "gain": "kp_rp", "new": 0.3})
        hub.on_points([AttitudePoint(1.01, "onboard", -0.1, 0.0, math.pi), AttitudePoint(1.0, "dcm", 0.0, 0.0, 0.0)])
        await asyncio.wait_for(flushed(hub, 2), 5)
        message, points = feed.take()  # queued: no writer attached
        return message, points, hub.frames_out

    message, points, frames_out = asyncio.run(run())
    frames = list(wire.decode(message))
    assert points == 3 and frames_out == 2
    assert [type(f).__name__ for f in frames] == ["PointsFrame", "dict", "PointsFrame"]
    first, gain, second = frames
    assert gain == {"type": "gain", "estimator": "dcm", "gain": "kp_rp", "new": 0.3}
    assert first.points["onboard"][0] == (1.0,)
    assert np.allclose([c[0] for c in first.points["onboard"][1:]], np.degrees([0.1, 0.2, 0.3]))
    assert second.seq == first.seq + 1 and set(second.points) == {"onboard", "dcm"}
    assert second.points["onboard"][3] == pytest.approx((180.0,))
