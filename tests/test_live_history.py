"""GET /api/history's reductions in the live store (gcs.server.live): min/max columns keep every
extreme, errors follow the page's rule across the ±180° wrap, and a reboot starts a new history."""

from __future__ import annotations

import numpy as np

from gcs.server.live_store import SeriesRing, decimate, error_series


def test_columns_keep_every_extreme_in_the_order_it_happened():
    t = np.arange(0.0, 60.0, 0.01)
    rpy = np.stack([np.sin(t), np.cos(t), np.zeros_like(t)], axis=1).astype(np.float32)
    rpy[3001, 2] = 42.0  # a one-sample spike
    rpy[3002, 2] = -7.0
    ct, cv = decimate(t, rpy, 0.5)
    assert len(ct) == 2 * 120  # two points per column, 120 columns
    assert cv[:, 2].max() == 42.0 and cv[:, 2].min() == -7.0
    k = int(np.argmax(cv[:, 2]))
    assert cv[k + 1, 2] == -7.0  # the spike came first, then the dip
    for axis in range(2):
        assert abs(cv[:, axis].max() - rpy[:, axis].max()) < 1e-6
        assert abs(cv[:, axis].min() - rpy[:, axis].min()) < 1e-6
    assert np.all(np.diff(ct) > 0) and ct[0] == 0.125 and ct[1] == 0.375


def test_errors_interpolate_the_estimator_the_short_way_round():
    ref_t = np.array([0.0, 0.5, 1.0, 1.5])
    ref = np.array([[0, 0, 179.0], [0, 0, -179.0], [0, 0, -178.0], [0, 0, 0]], dtype=np.float32)
    est_t = np.array([0.0, 1.0])
    est = np.array([[1, 0, 178.0], [1, 0, -176.0]], dtype=np.float32)  # 6° turn across the wrap
    t, e = error_series((est_t, est), (ref_t, ref))
    assert list(t) == [0.0, 0.5, 1.0]  # 1.5 s is past the estimator: not yet scored
    assert np.allclose(e[:, 0], 1.0)
    assert np.allclose(e[:, 2], [-1.0, 0.0, 2.0])  # 178 → 181 (= −179) → 184 (= −176)


def zeros(n: int) -> list[float]:
    return [0.0] * n


def test_history_serves_only_the_current_boot():
    ring = SeriesRing(1000)
    ring.extend([k * 0.1 for k in range(100)], zeros(100), zeros(100), zeros(100))
    ring.extend([9.95], [0.0], [0.0], [0.0])  # out of order by 50 ms: jitter, not a reboot
    assert len(ring.ordered()[0]) == 101
    # in one batch: a last sample of the old boot, then the clock back to 0 (a reboot)
    t = [10.0] + [k * 0.1 for k in range(20)]
    ring.extend(t, [0.0] + [1.0] * 20, [0.0] + [1.0] * 20, [0.0] + [1.0] * 20)
    t, rpy = ring.ordered()
    assert len(t) == 20 and t[0] == 0.0 and np.all(rpy == 1)
    t, _ = ring.between(0.5, 1.0)
    assert np.allclose(t, [0.6, 0.7, 0.8, 0.9, 1.0])


def test_a_ring_keeps_the_newest_samples_in_order_across_its_end():
    ring = SeriesRing(8)
    ring.extend([0.0, 1.0, 2.0, 3.0, 4.0], zeros(5), zeros(5), zeros(5))
    ring.ordered()  # read: the samples go into the arrays
    ring.extend([5.0, 6.0, 7.0, 8.0, 9.0, 10.0], zeros(6), zeros(6), [float(k) for k in range(6)])  # wraps
    t, rpy = ring.ordered()
    assert list(t) == [3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0]
    assert list(rpy[:, 2]) == [0.0, 0.0, 0.0, 1.0, 2.0, 3.0, 4.0, 5.0] and ring.count == 11
    ring.extend([float(k) for k in range(11, 31)], zeros(20), zeros(20), zeros(20))  # more than it holds
    assert list(ring.ordered()[0]) == [float(k) for k in range(23, 31)] and ring.count == 31
