"""The gyro bias is learned at rest, heading axis included, by every estimator (rest.py for dcm
and kf, zero-rate updates for ekf): without a magnetometer nothing else can teach the heading
part, and a still sensor's heading then drifts by the whole bias (0.4°/s here: 24° a minute)."""

import math

import numpy as np
import pytest
from synthetic import angle_between, static

from gcs.core.estimators import registry

BIAS = np.radians([0.3, -0.2, 0.4])  # rad/s, each axis


def turn_in_the_last_minute(est) -> float:
    """90 s still, tilted, no magnetometer, gyro biased: how far (deg) the estimate turns over
    the last 60 s."""
    samples = static(math.radians(10.0), math.radians(-5.0), math.radians(30.0), 50, 90, gyro=BIAS, mag=False)
    q = []
    for s in samples:
        est.update_imu(s)
        q.append(est.quaternion.copy())
    return angle_between(q[30 * 50], q[-1])


@pytest.mark.parametrize("name", registry.names())
def test_a_still_sensor_holds_its_heading_with_a_gyro_bias(name):
    assert turn_in_the_last_minute(registry.create(name)) < 0.5


@pytest.mark.parametrize("name", ["dcm", "kf"])
def test_without_rest_learning_it_drifts(name):
    """`rest_bias_tau` = 0: the heading drifts by most of the bias (so the test above can fail)."""
    assert turn_in_the_last_minute(registry.create(name, rest_bias_tau=0.0)) > 10.0
