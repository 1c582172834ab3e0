"""SSPD / Hausdorff: hand-computed values, traj-dist agreement, properties, chunking."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dashtraj.trajectory.metrics import (
    directed_hausdorff,
    hausdorff,
    point_to_polyline_distances,
    spd,
    sspd,
)
from dashtraj.trajectory.records import EmptyTrajectoryError, Trajectory

# --------------------------------------------------------------------------------------
# Reference: a plain double loop transcribing traj-dist's Euclidean code
# (bguillouet/traj-dist, traj_dist/cydist/basic_euclidean.pyx `_point_to_seg`,
# `_point_to_trajectory`; traj_dist/pydist/sspd.py `e_spd`/`e_sspd`;
# traj_dist/cydist/hausdorff.pyx `_e_directed_hausdorff`/`c_e_hausdorff`).
# Departures, as in dashtraj: a one-point trajectory is a point, and a segment whose
# squared length underflows to 0 is a point (traj-dist divides by zero there).
# --------------------------------------------------------------------------------------


def _ref_eucl(x1: float, y1: float, x2: float, y2: float) -> float:
    dx = x1 - x2
    dy = y1 - y2
    return math.sqrt(dx * dx + dy * dy)


def _ref_point_to_seg(px, py, p1x, p1y, p2x, p2y) -> float:
    segl = _ref_eucl(p1x, p1y, p2x, p2y)
    if segl * segl == 0:
        return min(_ref_eucl(px, py, p1x, p1y), _ref_eucl(px, py, p2x, p2y))
    u1 = ((px - p1x) * (p2x - p1x)) + ((py - p1y) * (p2y - p1y))
    u = u1 / (segl * segl)
    if (u < 0.00001) or (u > 1):
        ix = _ref_eucl(px, py, p1x, p1y)
        iy = _ref_eucl(px, py, p2x, p2y)
        return iy if ix > iy else ix
    ix = p1x + u * (p2x - p1x)
    iy = p1y + u * (p2y - p1y)
    return _ref_eucl(px, py, ix, iy)


def _ref_point_to_trajectory(px, py, t) -> float:
    if len(t) == 1:
        return _ref_eucl(px, py, t[0][0], t[0][1])
    best = 9e100
    for i in range(len(t) - 1):
        best = min(best, _ref_point_to_seg(px, py, t[i][0], t[i][1], t[i + 1][0], t[i + 1][1]))
    return best


def _ref_spd(t1, t2) -> float:
    return sum(_ref_point_to_trajectory(p[0], p[1], t2) for p in t1) / len(t1)


def ref_sspd(t1, t2) -> float:
    return (_ref_spd(t1, t2) + _ref_spd(t2, t1)) / 2


def ref_hausdorff(t1, t2) -> float:
    d12 = max(_ref_point_to_trajectory(p[0], p[1], t2) for p in t1)
    d21 = max(_ref_point_to_trajectory(p[0], p[1], t1) for p in t2)
    return max(d12, d21)


def _walk(rng: np.random.Generator, n: int) -> np.ndarray:
    return np.cumsum(rng.normal(scale=3.0, size=(n, 2)), axis=0)


# --------------------------------------------------------------------------------------
# Hand-computed values
# --------------------------------------------------------------------------------------


def test_parallel_segments_three_metres_apart():
    a = np.array([[0.0, 0.0], [10.0, 0.0]])
    b = np.array([[0.0, 3.0], [10.0, 3.0]])
    assert sspd(a, b) == pytest.approx(3.0, abs=1e-12)
    assert hausdorff(a, b) == pytest.approx(3.0, abs=1e-12)


def test_l_shape_vs_its_first_leg():
    # L: (0,0)->(10,0)->(10,10); line (0,0)->(10,0).
    # L's vertices to the line: 0, 0, 10 -> SPD 10/3; line's vertices lie on L -> 0.
    l_shape = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])
    line = np.array([[0.0, 0.0], [10.0, 0.0]])
    assert spd(l_shape, line) == pytest.approx(10 / 3, abs=1e-12)
    assert spd(line, l_shape) == pytest.approx(0.0, abs=1e-12)
    assert sspd(l_shape, line) == pytest.approx(5 / 3, abs=1e-12)
    assert hausdorff(l_shape, line) == pytest.approx(10.0, abs=1e-12)
    assert directed_hausdorff(line, l_shape) == pytest.approx(0.0, abs=1e-12)


def test_l_shape_vs_diagonal():
    # Corner (10,0) is 10/sqrt(2) = 5 sqrt(2) from the line y = x; other vertices on it.
    l_shape = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])
    diag = np.array([[0.0, 0.0], [10.0, 10.0]])
    assert sspd(l_shape, diag) == pytest.approx(5 * math.sqrt(2) / 6, abs=1e-12)
    assert hausdorff(l_shape, diag) == pytest.approx(5 * math.sqrt(2), abs=1e-12)


def test_point_vs_polyline():
    # The point is 4 m above the segment's middle; the segment's ends are sqrt(41) away.
    point = np.array([[5.0, 4.0]])
    line = np.array([[0.0, 0.0], [10.0, 0.0]])
    assert spd(point, line) == pytest.approx(4.0, abs=1e-12)
    assert spd(line, point) == pytest.approx(math.sqrt(41), abs=1e-12)
    assert sspd(point, line) == pytest.approx((4 + math.sqrt(41)) / 2, abs=1e-12)
    assert hausdorff(point, line) == pytest.approx(math.sqrt(41), abs=1e-12)


def test_point_to_polyline_distances_cases():
    line = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 0.0], [10.0, 10.0]])  # with a repeat
    pts = np.array([[5.0, -2.0], [13.0, -4.0], [-3.0, 4.0], [12.0, 5.0], [10.0, 10.0]])
    expected = [2.0, 5.0, 5.0, 2.0, 0.0]
    assert point_to_polyline_distances(pts, line) == pytest.approx(expected, abs=1e-12)


def test_traj_dist_small_projection_quirk_is_reproduced():
    # traj-dist uses the endpoint distance when the projection parameter u < 1e-5.
    line = np.array([[0.0, 0.0], [10.0, 0.0]])
    d = point_to_polyline_distances(np.array([[5e-5, 1.0]]), line)[0]
    assert d == pytest.approx(math.sqrt(5e-5**2 + 1.0), abs=1e-15)
    assert d - 1.0 == pytest.approx(1.25e-9, rel=1e-3)


def test_trajectory_objects_are_accepted():
    a = Trajectory(np.array([[0.0, 0.0], [10.0, 0.0]]), np.array([0.0, 1.0]))
    b = Trajectory(np.array([[0.0, 3.0], [10.0, 3.0]]))
    assert sspd(a, b) == pytest.approx(3.0)


@pytest.mark.parametrize("func", [spd, sspd, directed_hausdorff, hausdorff])
def test_empty_input_names_the_trajectory(func):
    good = np.array([[0.0, 0.0], [1.0, 0.0]])
    with pytest.raises(EmptyTrajectoryError, match="trajectory a is empty"):
        func(np.empty((0, 2)), good)
    with pytest.raises(EmptyTrajectoryError, match="trajectory b is empty"):
        func(good, [])
    assert issubclass(EmptyTrajectoryError, ValueError)


def test_bad_shape_is_a_value_error():
    with pytest.raises(ValueError, match="shape"):
        sspd(np.zeros((3, 3)), np.zeros((2, 2)))


# --------------------------------------------------------------------------------------
# Agreement with traj-dist (via the transcription above)
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(6))
def test_matches_traj_dist_transcription(seed):
    rng = np.random.default_rng(seed)
    a = _walk(rng, int(rng.integers(1, 60)))
    b = _walk(rng, int(rng.integers(1, 60)))
    assert abs(sspd(a, b) - ref_sspd(a, b)) <= 1e-9
    assert abs(hausdorff(a, b) - ref_hausdorff(a, b)) <= 1e-9


def test_matches_traj_dist_with_degenerate_and_grid_points():
    # Repeated vertices and points on segment ends exercise every branch.
    a = np.array([[0.0, 0.0], [0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [4.0, 4.0], [0.0, 4.0]])
    b = np.array([[1.0, 1.0], [4.0, 0.0], [2.0, 2.0], [2.0, 2.0], [-1.0, 5.0]])
    assert abs(sspd(a, b) - ref_sspd(a, b)) <= 1e-12
    assert abs(hausdorff(a, b) - ref_hausdorff(a, b)) <= 1e-12


# --------------------------------------------------------------------------------------
# Properties
# --------------------------------------------------------------------------------------

coord = st.floats(min_value=-1000, max_value=1000, allow_nan=False, allow_infinity=False)
polyline = st.lists(st.tuples(coord, coord), min_size=1, max_size=15).map(
    lambda pts: np.array(pts, dtype=np.float64)
)


@settings(max_examples=60, deadline=None)
@given(polyline, polyline)
def test_symmetry_and_order(a, b):
    s_ab, s_ba = sspd(a, b), sspd(b, a)
    h_ab, h_ba = hausdorff(a, b), hausdorff(b, a)
    assert s_ab == pytest.approx(s_ba, rel=1e-12, abs=1e-12)
    assert h_ab == h_ba
    assert 0.0 <= s_ab <= h_ab + 1e-9


@settings(max_examples=40, deadline=None)
@given(polyline)
def test_distance_to_itself_is_zero(a):
    # Zero up to rounding of the projection foot (coordinates are <= 1 km).
    assert sspd(a, a) == pytest.approx(0.0, abs=1e-9)
    assert hausdorff(a, a) == pytest.approx(0.0, abs=1e-9)


@settings(max_examples=40, deadline=None)
@given(polyline, polyline)
def test_agrees_with_traj_dist_transcription(a, b):
    assert abs(sspd(a, b) - ref_sspd(a, b)) <= 1e-9
    assert abs(hausdorff(a, b) - ref_hausdorff(a, b)) <= 1e-9


def _with_midpoints(a: np.ndarray) -> np.ndarray:
    out = [a[0]]
    for p, q in itertools.pairwise(a):
        out.extend([(p + q) / 2, q])
    return np.array(out)


@pytest.mark.parametrize("seed", range(5))
def test_resampling_makes_collinear_midpoints_irrelevant(seed):
    rng = np.random.default_rng(100 + seed)
    a = _walk(rng, 12)
    b = _walk(rng, 9)
    a2 = _with_midpoints(a)
    # Without resampling the extra vertices change the value ...
    assert abs(sspd(a, b) - sspd(a2, b)) > 1e-6
    # ... with it they do not.
    for step in (0.5, 1.7):
        assert sspd(a, b, resample_m=step) == pytest.approx(sspd(a2, b, resample_m=step), abs=1e-9)
        assert hausdorff(a, b, resample_m=step) == pytest.approx(
            hausdorff(a2, b, resample_m=step), abs=1e-9
        )


def test_chunking_gives_identical_results():
    rng = np.random.default_rng(7)
    a = _walk(rng, 301)
    b = _walk(rng, 257)
    whole = point_to_polyline_distances(a, b, chunk_elements=10**9)
    for chunk in (1, 7, 256, 1000):
        np.testing.assert_array_equal(
            point_to_polyline_distances(a, b, chunk_elements=chunk), whole
        )
    assert sspd(a, b, chunk_elements=13) == sspd(a, b)
    assert hausdorff(a, b, chunk_elements=13) == hausdorff(a, b)


# --------------------------------------------------------------------------------------
# Trajectory record
# --------------------------------------------------------------------------------------


def test_resample_keeps_endpoints_and_interpolates_time():
    tr = Trajectory(np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 5.0]]), np.array([0.0, 10.0, 20.0]))
    r = tr.resample(4.0)
    np.testing.assert_allclose(r.points, [[0, 0], [4, 0], [8, 0], [10, 2], [10, 5]], atol=1e-12)
    np.testing.assert_allclose(r.t, [0, 4, 8, 14, 20], atol=1e-12)
    assert tr.length_m == 15.0
    assert r.length_m == pytest.approx(4 + 4 + math.hypot(2, 2) + 3)


def test_trajectory_is_read_only_and_validated():
    src = np.array([[0.0, 0.0], [1.0, 1.0]])
    tr = Trajectory(src)
    src[0, 0] = 99.0
    assert tr.points[0, 0] == 0.0
    with pytest.raises(ValueError):
        tr.points[0, 0] = 5.0
    with pytest.raises(ValueError, match="shape"):
        Trajectory(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="not finite"):
        Trajectory(np.array([[0.0, np.nan]]))
    with pytest.raises(ValueError, match="shape"):
        Trajectory(src, np.zeros(3))
    with pytest.raises(EmptyTrajectoryError):
        Trajectory(np.empty((0, 2)))


def test_memory_stays_bounded_for_10k_point_trajectories():
    import tracemalloc

    rng = np.random.default_rng(11)
    a = _walk(rng, 10_000)
    b = _walk(rng, 10_000)
    tracemalloc.start()
    try:
        d = point_to_polyline_distances(a, b)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert d.shape == (10_000,)
    # A dense 10k x 10k x 2 float64 temporary would be 1.6 GB; chunks stay ~ MB.
    assert peak < 50 * 2**20
