"""The pruned point-to-polyline kernel equals the dense one bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from dashtraj.trajectory.metrics import (
    _dense_distances,
    _pruned_distances,
    hausdorff,
    point_to_polyline_distances,
    sspd,
)


@pytest.mark.parametrize("seed", range(12))
def test_pruned_equals_dense(seed):
    rng = np.random.default_rng(seed)
    n, m = int(rng.integers(50, 600)), int(rng.integers(50, 600))
    a = np.cumsum(rng.normal(size=(n, 2)) * rng.uniform(0.1, 5.0), axis=0)
    b = np.cumsum(rng.normal(size=(m, 2)) * rng.uniform(0.1, 5.0), axis=0)
    b[5:9] = b[5]  # zero-length segments are points
    a[:20] = b[:20] + 1e-7  # points on the polyline: traj-dist's u < 1e-5 endpoint rule
    pruned = _pruned_distances(a, b)
    assert pruned is not None
    assert np.array_equal(pruned, _dense_distances(a, b, 32_768))


def test_long_segments_fall_back_to_dense():
    rng = np.random.default_rng(3)
    a = rng.uniform(-500, 500, size=(300, 2))
    b = np.array([[-1000.0, 0.0], [1000.0, 0.0], [1000.0, 5.0], [-1000.0, 5.0]] * 60)
    assert _pruned_distances(a, b) is None  # every segment is a candidate
    d = point_to_polyline_distances(a, b)
    assert np.array_equal(d, _dense_distances(a, b, 32_768))


def test_public_metrics_use_either_kernel_with_the_same_result():
    rng = np.random.default_rng(9)
    a = np.cumsum(rng.normal(size=(800, 2)), axis=0)
    b = np.cumsum(rng.normal(size=(700, 2)), axis=0)
    dense_ab, dense_ba = _dense_distances(a, b, 32_768), _dense_distances(b, a, 32_768)
    assert sspd(a, b) == (dense_ab.mean() + dense_ba.mean()) / 2
    assert hausdorff(a, b) == max(dense_ab.max(), dense_ba.max())
