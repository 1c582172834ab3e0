"""Distances between trajectories: SPD, SSPD and Hausdorff (paper Sec. II.F).

Definitions follow traj-dist (Besse et al., https://github.com/bguillouet/traj-dist,
``traj_dist/pydist/sspd.py``, ``hausdorff.py``, ``basic_euclidean.py`` and their
Cython twins) EXACTLY, Euclidean 2-D case, because the paper's figures were made
with it. SSPD was introduced in

    P. Besse, B. Guillouet, J.-M. Loubes, F. Royer, "Review and perspective for
    distance based clustering of vehicle trajectories", IEEE Trans. ITS 17(11),
    2016 (arXiv:1508.04904).

* point-to-trajectory distance D(p, T): the minimum over the segments of T of the
  point-to-segment distance;
* SPD(T1, T2) = mean over the vertices p of T1 of D(p, T2)            (Eq. 11);
* SSPD(T1, T2) = (SPD(T1, T2) + SPD(T2, T1)) / 2                        (Eq. 12);
* directed Hausdorff H(T1, T2) = max over the vertices p of T1 of D(p, T2);
* Hausdorff(T1, T2) = max(H(T1, T2), H(T2, T1))                          (Eq. 14).

Note that traj-dist's Hausdorff, like its SSPD, measures from each *vertex* to
the other trajectory's *segments*, not vertex to vertex as the paper's Eq. 13
reads; dashtraj matches traj-dist, so its values are comparable with the paper's.

traj-dist's point-to-segment distance has a quirk that is reproduced here so the
values agree to rounding: with u the projection parameter of the point on the
segment (0 at its start, 1 at its end), the perpendicular distance is used only
for 1e-5 <= u <= 1; for u < 1e-5 (not just u < 0) the nearer endpoint distance is
taken. The deviation from the exact distance is at most about 1e-5 of the
segment length. A zero-length segment is a point.
(Also one whose squared length underflows to zero, where traj-dist divides by 0.)

Departure from traj-dist: a one-point trajectory is treated as a point (traj-dist
returns 9e100 or fails there), so D(p, T) is the distance to that point.

Distances are Euclidean in the plane (CARLA world, metres); the paper uses the
Euclidean system too. Optional arc-length resampling (`resample_m`) makes the
values independent of how densely each trajectory is sampled; it is off by
default so figures stay comparable with the paper.
"""

from __future__ import annotations

import numpy as np

from dashtraj.trajectory.records import EmptyTrajectoryError, Trajectory

_U_MIN = 1e-5
"""traj-dist's threshold below which the endpoint distance replaces the projection."""

DEFAULT_CHUNK_ELEMENTS = 1 << 15
"""Point x segment pairs evaluated at once: 7 float64 buffers of 256 KiB (cache-sized)."""


def _as_points(traj: Trajectory | np.ndarray, name: str) -> np.ndarray:
    """(N, 2) float64 array of a Trajectory or array-like; errors name `name`."""
    pts = traj.points if isinstance(traj, Trajectory) else np.asarray(traj, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        if pts.size == 0:
            raise EmptyTrajectoryError(f"trajectory {name} is empty (no points)")
        raise ValueError(f"trajectory {name} must have shape (N, 2), got {pts.shape}")
    if pts.shape[0] == 0:
        raise EmptyTrajectoryError(f"trajectory {name} is empty (no points)")
    if not np.isfinite(pts).all():
        raise ValueError(f"trajectory {name} has non-finite coordinates")
    return pts


def _prepare(traj: Trajectory | np.ndarray, name: str, resample_m: float | None) -> np.ndarray:
    pts = _as_points(traj, name)
    if resample_m is None:
        return pts
    return Trajectory(pts).resample(resample_m).points


def point_to_polyline_distances(
    points: Trajectory | np.ndarray,
    polyline: Trajectory | np.ndarray,
    *,
    chunk_elements: int = DEFAULT_CHUNK_ELEMENTS,
) -> np.ndarray:
    """Distance from each point to the nearest segment of a polyline.

    Point-to-segment distance as in traj-dist (see the module docstring for its
    u < 1e-5 rule); a zero-length segment and a one-point polyline are points.

    Args:
        points: (N, 2) float, CARLA world, metres (or a Trajectory).
        polyline: (M, 2) float, CARLA world, metres (or a Trajectory), M >= 1.
        chunk_elements: at most this many point x segment pairs are evaluated
            at once, bounding memory (7 float64 and 2 bool buffers of this
            size, reused; at least one row of M pairs).

    Returns:
        (N,) float64 distances, metres.

    Raises:
        EmptyTrajectoryError: `points` or `polyline` has no points.
        ValueError: wrong shape or non-finite coordinates.

    Example:
        >>> point_to_polyline_distances(np.array([[5.0, 3.0]]),
        ...                             np.array([[0.0, 0.0], [10.0, 0.0]]))
        array([3.])
    """
    p = _as_points(points, "points")
    q = _as_points(polyline, "polyline")
    if p.shape[0] * q.shape[0] >= PRUNE_MIN_PAIRS and q.shape[0] > 2:
        pruned = _pruned_distances(p, q)
        if pruned is not None:
            return pruned
    return _dense_distances(p, q, chunk_elements)


PRUNE_MIN_PAIRS = 50_000
"""Below this many point × segment pairs the dense kernel is as fast as pruning."""


def _pair_sq_distances(px, py, ax, ay, bx, by) -> np.ndarray:
    """traj-dist's point-to-segment distance, squared, for aligned pair arrays.

    The same operations in the same order as the dense kernel, so the values are
    bit-identical to it (and to traj-dist after the square root).
    """
    dx = bx - ax
    dy = by - ay
    segl = np.sqrt(dx * dx + dy * dy)
    seg2 = segl * segl
    degenerate = seg2 == 0
    vx, vy = px - ax, py - ay
    wx, wy = px - bx, py - by
    va2 = vx * vx
    va2 += vy * vy
    vb2 = wx * wx
    vb2 += wy * wy
    with np.errstate(over="ignore", invalid="ignore"):
        u = vx * dx
        u += vy * dy
        u /= np.where(degenerate, 1.0, seg2)
        fx = u * dx
        fx += ax
        fx = px - fx
        fy = u * dy
        fy += ay
        fy = py - fy
        fx *= fx
        fy *= fy
        fx += fy
    endpoint = (u < _U_MIN) | (u > 1.0) | degenerate
    return np.where(endpoint, np.minimum(va2, vb2), fx)


def _pruned_distances(p: np.ndarray, q: np.ndarray) -> np.ndarray | None:
    """Exact point-to-polyline distances evaluating only the segments that can win.

    The nearest vertex of the polyline is at distance r0 from a point, and
    traj-dist's distance to a segment ending there is at most r0. A segment of
    half-length h whose midpoint is farther than r0 + h is farther than r0 from
    the point, so it cannot be the nearest: only midpoints within r0 + max(h)
    are candidates (a k-d tree finds them). Returns None when that prunes too
    little to pay (long segments), for the dense kernel to take over.
    """
    from scipy.spatial import cKDTree

    n, m = p.shape[0], q.shape[0]
    half = 0.5 * np.hypot(q[1:, 0] - q[:-1, 0], q[1:, 1] - q[:-1, 1])
    r0, _ = cKDTree(q).query(p)
    radius = r0 + half.max()
    radius += 1e-9 * (1.0 + radius)  # rounding slack: never drop the winner
    mids = cKDTree(0.5 * (q[1:] + q[:-1]))
    lists = mids.query_ball_point(p, radius, return_sorted=False)
    counts = np.fromiter((len(c) for c in lists), dtype=np.int64, count=n)
    total = int(counts.sum())
    if total > 0.2 * n * (m - 1):
        return None
    seg = np.fromiter((j for c in lists for j in c), dtype=np.int64, count=total)
    pt = np.repeat(np.arange(n), counts)
    d2 = _pair_sq_distances(p[pt, 0], p[pt, 1], q[seg, 0], q[seg, 1],
                            q[seg + 1, 0], q[seg + 1, 1])
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    out = np.minimum.reduceat(d2, starts)
    np.sqrt(out, out=out)
    return out


def _dense_distances(p: np.ndarray, q: np.ndarray, chunk_elements: int) -> np.ndarray:
    """Every point against every segment, in chunks of at most `chunk_elements` pairs."""
    n, m = p.shape[0], q.shape[0]
    out = np.empty(n, dtype=np.float64)
    s1 = q[:-1]
    dx = q[1:, 0] - s1[:, 0]
    dy = q[1:, 1] - s1[:, 1]
    segl = np.sqrt(dx * dx + dy * dy)
    seg2 = segl * segl
    # A zero-length segment is a point (traj-dist tests dx == dy == 0; a segment so
    # short that its squared length underflows to 0 is treated the same way here).
    degenerate = seg2 == 0
    safe_seg2 = np.where(degenerate, 1.0, seg2)
    if m == 1:
        v = p - q[0]
        return np.sqrt((v * v).sum(axis=1))
    qx, qy = q[:, 0], q[:, 1]
    s1x, s1y = qx[:-1], qy[:-1]
    rows = max(1, min(n, int(chunk_elements) // m))
    # Work buffers reused across chunks; every temporary is (rows, M) or (rows, M-1).
    vx, vy, v2 = (np.empty((rows, m)) for _ in range(3))
    u, fx, fy, tmp = (np.empty((rows, m - 1)) for _ in range(4))
    mask, mask2 = np.empty((rows, m - 1), dtype=bool), np.empty((rows, m - 1), dtype=bool)
    # Squared distances throughout and one square root at the end: sqrt is monotonic
    # and correctly rounded, so sqrt(min(d^2)) == min(sqrt(d^2)) bit for bit, the
    # value traj-dist gets by taking sqrt per pair.
    for start in range(0, n, rows):
        c = min(rows, n - start)
        px = p[start : start + c, 0:1]
        py = p[start : start + c, 1:2]
        bvx, bvy, bv2 = vx[:c], vy[:c], v2[:c]
        bu, bfx, bfy, btmp = u[:c], fx[:c], fy[:c], tmp[:c]
        bmask, bmask2 = mask[:c], mask2[:c]
        np.subtract(px, qx, out=bvx)
        np.subtract(py, qy, out=bvy)
        np.multiply(bvx, bvx, out=bv2)
        bv2 += bvy * bvy  # squared distance to every vertex
        with np.errstate(over="ignore", invalid="ignore"):  # masked out below
            # u = ((p - s1) . (s2 - s1)) / |s2 - s1|^2, as traj-dist.
            np.multiply(bvx[:, :-1], dx, out=bu)
            np.multiply(bvy[:, :-1], dy, out=btmp)
            bu += btmp
            bu /= safe_seg2
            # Projection foot s1 + u (s2 - s1); squared distance from p to it.
            np.multiply(bu, dx, out=bfx)
            bfx += s1x
            np.subtract(px, bfx, out=bfx)
            np.multiply(bu, dy, out=bfy)
            bfy += s1y
            np.subtract(py, bfy, out=bfy)
            bfx *= bfx
            bfy *= bfy
            bfx += bfy  # perpendicular distance squared
        # traj-dist: endpoint distance when u < 1e-5 or u > 1 (or a point segment).
        np.less(bu, _U_MIN, out=bmask)
        np.greater(bu, 1.0, out=bmask2)
        bmask |= bmask2
        bmask |= degenerate
        np.minimum(bv2[:, :-1], bv2[:, 1:], out=btmp)
        np.copyto(bfx, btmp, where=bmask)
        out[start : start + c] = bfx.min(axis=1)
    np.sqrt(out, out=out)
    return out


def spd(
    a: Trajectory | np.ndarray,
    b: Trajectory | np.ndarray,
    *,
    resample_m: float | None = None,
    chunk_elements: int = DEFAULT_CHUNK_ELEMENTS,
) -> float:
    """Segment-Path Distance from `a` to `b` (paper Eq. 11; not symmetric).

    Mean over the vertices of `a` of their distance to the segments of `b`.

    Args:
        a, b: (N, 2) / (M, 2) float, CARLA world, metres, or Trajectory.
        resample_m: if given, both are first resampled every this many metres
            of arc length (`Trajectory.resample`); None (default) uses the
            vertices as given, as traj-dist and the paper do.
        chunk_elements: memory bound, see `point_to_polyline_distances`.

    Returns:
        SPD in metres.

    Raises:
        EmptyTrajectoryError: `a` or `b` has no points (the message says which).

    Example:
        >>> spd(np.array([[0.0, 3.0], [10.0, 3.0]]), np.array([[0.0, 0.0], [10.0, 0.0]]))
        3.0
    """
    pa = _prepare(a, "a", resample_m)
    pb = _prepare(b, "b", resample_m)
    return float(point_to_polyline_distances(pa, pb, chunk_elements=chunk_elements).mean())


def sspd(
    a: Trajectory | np.ndarray,
    b: Trajectory | np.ndarray,
    *,
    resample_m: float | None = None,
    chunk_elements: int = DEFAULT_CHUNK_ELEMENTS,
) -> float:
    """Symmetrized Segment-Path Distance (Besse et al. 2016; paper Eq. 12).

    SSPD(a, b) = (SPD(a, b) + SPD(b, a)) / 2, as traj-dist ``e_sspd``.

    Args:
        a, b: (N, 2) / (M, 2) float, CARLA world, metres, or Trajectory.
        resample_m: optional arc-length resampling step, metres (see `spd`).
        chunk_elements: memory bound, see `point_to_polyline_distances`.

    Returns:
        SSPD in metres.

    Raises:
        EmptyTrajectoryError: `a` or `b` has no points (the message says which).

    Example:
        >>> sspd(np.array([[0.0, 3.0], [10.0, 3.0]]), np.array([[0.0, 0.0], [10.0, 0.0]]))
        3.0
    """
    pa = _prepare(a, "a", resample_m)
    pb = _prepare(b, "b", resample_m)
    d_ab = point_to_polyline_distances(pa, pb, chunk_elements=chunk_elements).mean()
    d_ba = point_to_polyline_distances(pb, pa, chunk_elements=chunk_elements).mean()
    return float((d_ab + d_ba) / 2)


def directed_hausdorff(
    a: Trajectory | np.ndarray,
    b: Trajectory | np.ndarray,
    *,
    resample_m: float | None = None,
    chunk_elements: int = DEFAULT_CHUNK_ELEMENTS,
) -> float:
    """Directed Hausdorff distance from `a` to `b` (paper Eq. 13, traj-dist form).

    Max over the vertices of `a` of their distance to the *segments* of `b`, as
    traj-dist ``e_directed_hausdorff`` (not vertex to vertex).

    Args:
        a, b: (N, 2) / (M, 2) float, CARLA world, metres, or Trajectory.
        resample_m: optional arc-length resampling step, metres (see `spd`).
        chunk_elements: memory bound, see `point_to_polyline_distances`.

    Returns:
        Directed Hausdorff distance in metres.

    Raises:
        EmptyTrajectoryError: `a` or `b` has no points (the message says which).

    Example:
        >>> directed_hausdorff(np.array([[5.0, 2.0]]), np.array([[0.0, 0.0], [10.0, 0.0]]))
        2.0
    """
    pa = _prepare(a, "a", resample_m)
    pb = _prepare(b, "b", resample_m)
    return float(point_to_polyline_distances(pa, pb, chunk_elements=chunk_elements).max())


def hausdorff(
    a: Trajectory | np.ndarray,
    b: Trajectory | np.ndarray,
    *,
    resample_m: float | None = None,
    chunk_elements: int = DEFAULT_CHUNK_ELEMENTS,
) -> float:
    """Hausdorff distance (paper Eq. 14): max of the two directed distances.

    Vertex-to-segment form, as traj-dist ``e_hausdorff``; symmetric.

    Args:
        a, b: (N, 2) / (M, 2) float, CARLA world, metres, or Trajectory.
        resample_m: optional arc-length resampling step, metres (see `spd`).
        chunk_elements: memory bound, see `point_to_polyline_distances`.

    Returns:
        Hausdorff distance in metres.

    Raises:
        EmptyTrajectoryError: `a` or `b` has no points (the message says which).

    Example:
        >>> hausdorff(np.array([[0.0, 3.0], [10.0, 3.0]]), np.array([[0.0, 0.0], [10.0, 0.0]]))
        3.0
    """
    pa = _prepare(a, "a", resample_m)
    pb = _prepare(b, "b", resample_m)
    d_ab = point_to_polyline_distances(pa, pb, chunk_elements=chunk_elements).max()
    d_ba = point_to_polyline_distances(pb, pa, chunk_elements=chunk_elements).max()
    return float(max(d_ab, d_ba))
