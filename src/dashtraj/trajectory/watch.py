"""Negative evidence for the gate: places the observers watched and saw empty.

The road-network gate (`dashtraj.trajectory.gating`) asks whether one car *could*
have driven from one sighting to the next in the time between them. It cannot tell
the target from an exact look-alike that was somewhere the target could also have
been. What can, sometimes, is what the observers did *not* see: if the target drove
from sighting a to sighting b, it was on the road between them at every moment in
between; where every way it could have taken led, at some moment, through a place a
camera was looking at and saw empty then, it did not make that drive, and the two
sightings are of two vehicles. This module is that test (`Watch.drive_unseen`), given to
`gate_tracks` as its ``watch``.

**Where the car could have been.** The lane graph's driving lanes are cut into points
every ``step_m``. The car starts at a: any point within the gate's ``slack_m`` (or
``end_m``) + ``step_m`` of a's lane points along the lanes, ahead or behind (localization
error). From one frame time to the next (every frame of every camera strictly between ta
and tb, in time order) it moves at most ``max_speed_mps`` times the time between along the
lanes, in hops of ``step_m`` rounded up: on along its lane, into a successor, across to a
neighbouring lane of one road section driving the same way (at no cost), or not at all;
and it stays where it can still reach b in time. It must end as near b, ahead or behind.
The route costs are lower bounds and the hops round up, so the places are, if anything,
too many: the test errs towards "could have been unseen".

**Watched and empty.** A place is watched by a camera in a frame when it lies within
``near_m`` to ``range_m`` of the camera, inside its horizontal field of view less
``fov_margin_deg`` on each side, with a clear line of sight over open ground (every point
of the sight line within ``open_m`` of the centre of some lane of any type: driving lanes,
sidewalks, shoulders, parking; a building's corner is off every lane); and empty when no
box that camera detected in that frame (any class, any score, tracked or not) spans its
bearing, widened by ``box_margin_deg``. A box anywhere in that direction, nearer or
farther, may be the car itself or something hiding it, so it counts as "maybe there".

**Two vehicles** when a way from a to b exists on these lanes, but none keeps the car out
of watched, empty places in all but ``misses`` frames (a space-time reachability filter
that carries the number of such frames used). Where no way exists at all, that is the
gate's reachability to judge, not evidence. The detector can miss a car in a frame;
``misses`` lets one car do that before it is split in two.

Units: seconds, metres, degrees; positions in CARLA world coordinates (as the sightings'
``x``, ``y``; yaw as `Sighting.observer_yaw`, bearing + to the right).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from dashtraj.errors import DashtrajError
from dashtraj.roads import RoadMap, Waypoint


class WatchError(DashtrajError, ValueError):
    """Bad watch input: a camera view without frames, a bad setting."""


@dataclass(frozen=True, slots=True)
class WatchConfig:
    """Settings of the negative-evidence test (module docstring).

    Attributes:
        range_m: a camera sees a vehicle within this distance, metres (the ReID range:
            a car there is 30 px tall or more at 640 × 360 and 90° FOV).
        near_m: nor closer than this, metres (below the frame, or cut by its edge).
        fov_margin_deg: the field of view's edges not counted, each side, degrees (a car
            there is cut by the frame's edge).
        box_margin_deg: a detected box covers its bearings widened by this, each side.
        open_m: a sight line is clear where every point of it lies within this of some
            lane's centre (any lane type), metres.
        step_m: spacing of the lane points the car could be at, metres.
        misses: frames in which the car may have been in a watched place that was seen
            empty (a detector's miss) before a way is ruled out.
        end_m: the car starts and ends within this (plus `step_m`) of the two sightings'
            lane points, metres (their localization error); None: the gate's slack.
    """

    range_m: float = 15.0
    near_m: float = 4.0
    fov_margin_deg: float = 5.0
    box_margin_deg: float = 2.0
    open_m: float = 3.0
    step_m: float = 2.0
    misses: int = 1
    end_m: float | None = None

    def __post_init__(self) -> None:
        for name in ("range_m", "near_m", "fov_margin_deg", "box_margin_deg", "open_m",
                     "step_m"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise WatchError(f"WatchConfig.{name} must be a finite number >= 0, got {v!r}")
        if self.end_m is not None and not (isinstance(self.end_m, int | float)
                                           and math.isfinite(self.end_m) and self.end_m >= 0):
            raise WatchError(f"WatchConfig.end_m must be None or a finite number >= 0, got "
                             f"{self.end_m!r}")
        if self.step_m <= 0 or self.range_m <= self.near_m:
            raise WatchError(f"WatchConfig: step_m > 0 and range_m > near_m, got "
                             f"{self.step_m!r}, {self.range_m!r}, {self.near_m!r}")
        if not (isinstance(self.misses, int) and self.misses >= 0):
            raise WatchError(f"WatchConfig.misses must be an integer >= 0, got "
                             f"{self.misses!r}")


@dataclass(frozen=True, slots=True)
class CameraViews:
    """What one observer's camera looked at, frame by frame.

    Attributes:
        t: (F,) frame times, seconds, increasing.
        x, y: (F,) camera positions, metres.
        yaw_deg: (F,) camera headings, degrees.
        fov_deg: the horizontal field of view, degrees.
        boxes: F arrays (K, 2) of the detected boxes' bearings, left and right edge,
            degrees (+ right of the optical axis), one row per box of that frame.
    """

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw_deg: np.ndarray
    fov_deg: float
    boxes: Sequence[np.ndarray]


def box_bearings(x0, x1, width_px: float, fov_deg: float) -> np.ndarray:
    """Bearings (degrees, + right) of boxes' left and right edges, (K, 2), for a pinhole
    camera of `width_px` and horizontal `fov_deg`."""
    f = width_px / (2.0 * math.tan(math.radians(fov_deg) / 2.0))
    u = np.column_stack([np.asarray(x0, np.float64), np.asarray(x1, np.float64)])
    return np.degrees(np.arctan((u - width_px / 2.0) / f)).reshape(-1, 2)


class Watch:
    """Where the observers looked, and the test `drive_unseen` (module docstring).

    Args:
        road_map: the map.
        views: one `CameraViews` per observer (frames on any clock; a frame is used when
            its time lies strictly between the two sightings).
        config: `WatchConfig`.
    """

    def __init__(self, road_map: RoadMap, views: Sequence[CameraViews],
                 config: WatchConfig = WatchConfig()):
        self.map = road_map
        self.cfg = config
        self.views = list(views)
        for i, v in enumerate(self.views):
            if len(v.t) == 0 or len(v.boxes) != len(v.t):
                raise WatchError(f"camera view {i}: {len(v.t)} frames and {len(v.boxes)} box "
                                 f"lists (need one list per frame, at least one frame)")
        # every frame of every camera, in time order: (t, camera, frame index)
        ts = np.concatenate([v.t for v in self.views]) if self.views else np.zeros(0)
        cam = np.concatenate([np.full(len(v.t), i) for i, v in enumerate(self.views)]) \
            if self.views else np.zeros(0, int)
        idx = np.concatenate([np.arange(len(v.t)) for v in self.views]) \
            if self.views else np.zeros(0, int)
        o = np.lexsort((cam, ts))
        self._ft, self._fcam, self._fidx = ts[o], cam[o], idx[o]
        self._lanes_cache: dict = {}
        self._points()
        self._open = cKDTree(np.column_stack([road_map._vx, road_map._vy]))

    # ------------------------------------------------------------- lane points
    def _points(self) -> None:
        """Points every `step_m` along every driving lane of the lane graph: their
        progress along their lane, their positions, and each lane's slice of them."""
        g = self.map.lane_graph(0.0)
        self.graph = g
        prog, xs, ys = [], [], []
        self._lane_index: dict = {}
        for key, length in g._length.items():
            n = max(1, math.ceil(length / self.cfg.step_m))
            p = np.linspace(0.0, length, n + 1)
            s = np.array([g.s_at_progress(key, float(v)) for v in p])
            xy = g._points_at(key, s)
            self._lane_index[key] = (len(prog), len(prog) + len(p))
            prog.extend(p)
            xs.extend(xy[:, 0])
            ys.extend(xy[:, 1])
        self._n = len(prog)
        self._prog = np.asarray(prog)
        self._xy = np.column_stack([xs, ys])
        self._lane_keys = list(self._lane_index)
        self._corridors()

    def _corridors(self) -> None:
        """One road section's lanes driving one way form a corridor: a car changes
        between them anywhere, at no cost (a lower bound), and leaves by any of their
        successors."""
        g = self.graph
        group: dict = {}
        for key in self._lane_keys:
            group.setdefault((key[0], key[1], key[2] > 0), []).append(key)
        self._corr = list(group.values())
        self._corr_of = {k: ci for ci, ks in enumerate(self._corr) for k in ks}
        self._corr_len = np.array([min(g._length[k] for k in ks) for ks in self._corr])
        self._corr_pts = [np.concatenate([np.arange(*self._lane_index[k]) for k in ks])
                          for ks in self._corr]
        succ: list[set] = [set() for _ in self._corr]
        for k in self._lane_keys:
            for nxt, _w, is_lc in g._adj[k]:
                if not is_lc and nxt in self._corr_of:
                    succ[self._corr_of[k]].add(self._corr_of[nxt])
        self._succ = [sorted(s) for s in succ]
        pred: list[list] = [[] for _ in self._corr]
        for c, ss in enumerate(self._succ):
            for d in ss:
                pred[d].append(c)
        self._pred = pred

    def _dijkstra(self, sources: list[tuple[tuple, float]], reverse: bool) -> np.ndarray:
        """Least route cost from the sources (lane, progress) to every lane point
        (forward), or from every lane point to them (reverse), metres: lower bounds
        (corridors, `_corridors`)."""
        n = len(self._corr)
        out = np.full(self._n, math.inf)
        best = np.full(n, math.inf)  # forward: cost to a corridor's start; reverse: from it
        heap: list = []
        for key, p0 in sources:
            c = self._corr_of.get(key)
            if c is None:
                continue
            idx = self._corr_pts[c]
            pr = self._prog[idx]
            if not reverse:  # on from the source along its corridor, then out of it
                out[idx] = np.minimum(out[idx], np.where(pr >= p0 - 1e-9, pr - p0, math.inf))
                for d in self._succ[c]:
                    heapq.heappush(heap, (max(self._corr_len[c] - p0, 0.0), d))
            else:  # from the corridor's start, or any point before the source, to it
                out[idx] = np.minimum(out[idx], np.where(pr <= p0 + 1e-9, p0 - pr, math.inf))
                heapq.heappush(heap, (p0, c))
        while heap:
            cost, c = heapq.heappop(heap)
            if cost >= best[c]:
                continue
            best[c] = cost
            idx = self._corr_pts[c]
            if not reverse:
                out[idx] = np.minimum(out[idx], cost + self._prog[idx])
                for d in self._succ[c]:
                    heapq.heappush(heap, (cost + self._corr_len[c], d))
            else:
                for u in self._pred[c]:  # through u, from any of its points, into c
                    ui = self._corr_pts[u]
                    out[ui] = np.minimum(out[ui], np.maximum(
                        self._corr_len[u] - self._prog[ui], 0.0) + cost)
                    heapq.heappush(heap, (self._corr_len[u] + cost, u))
        return out

    def _costs(self, points: Sequence[Waypoint], reverse: bool) -> np.ndarray:
        sources = tuple(sorted((wp.key, round(self.graph.progress(wp.key, wp.s), 3))
                               for wp in points if wp.key in self.graph._length))
        hit = self._lanes_cache.get((sources, reverse))
        if hit is None:
            hit = self._dijkstra(list(sources), reverse)
            self._lanes_cache[(sources, reverse)] = hit
        return hit

    # ------------------------------------------------------------- the test
    def _steps(self) -> None:
        """The one-hop moves between lane points (at most `step_m` of driving): on along a
        lane, into a successor lane, across to the same place of a neighbouring lane of
        the corridor, or standing still; a sparse (N, N) matrix."""
        from scipy.sparse import csr_matrix

        rows, cols = [np.arange(self._n)], [np.arange(self._n)]
        g = self.graph
        for key, (a, b) in self._lane_index.items():
            rows.append(np.arange(a, b - 1))
            cols.append(np.arange(a + 1, b))
            for nxt, _w, is_lc in g._adj[key]:
                if not is_lc and nxt in self._lane_index:
                    rows.append(np.array([b - 1]))
                    cols.append(np.array([self._lane_index[nxt][0]]))
        for ks in self._corr:
            for k in ks:
                a, b = self._lane_index[k]
                for k2 in ks:
                    if k2 == k:
                        continue
                    a2, b2 = self._lane_index[k2]
                    j = np.clip(np.searchsorted(self._prog[a2:b2], self._prog[a:b]), 0,
                                b2 - a2 - 1)
                    rows.append(np.arange(a, b))
                    cols.append(a2 + j)
        r, c = np.concatenate(rows), np.concatenate(cols)
        n = self._n
        self._step = csr_matrix((np.ones(len(r), np.float32), (c, r)), shape=(n, n))

    def _expand(self, reach: np.ndarray, metres: float) -> np.ndarray:
        """Lane points within `metres` of driving from any point of `reach` (bool (N,))."""
        if not reach.any():
            return reach
        for _ in range(max(1, math.ceil(metres / self.cfg.step_m))):
            reach = (self._step @ reach.astype(np.float32)) > 0
        return reach

    def drive_unseen(self, ta: float, points_a: Sequence[Waypoint], tb: float,
                     points_b: Sequence[Waypoint], max_speed_mps: float,
                     slack_m: float) -> bool:
        """Whether one car could have driven from a (time `ta`, lane points `points_a`)
        to b (`tb`, `points_b`) without the cameras seeing it (module docstring): False
        when every way there crossed, in more than ``misses`` frames, a place a camera
        watched and saw empty at that moment."""
        if tb <= ta or not points_a or not points_b or not self.views:
            return True
        lo, hi = np.searchsorted(self._ft, ta, "right"), np.searchsorted(self._ft, tb, "left")
        if hi - lo <= self.cfg.misses:
            return True
        if not hasattr(self, "_step"):
            self._steps()
        ca, ra = self._costs(points_a, False), self._costs(points_a, True)
        cb, rb = self._costs(points_b, True), self._costs(points_b, False)
        tol = (slack_m if self.cfg.end_m is None else self.cfg.end_m) + self.cfg.step_m
        end = (cb <= tol) | (rb <= tol)  # at b, up to its localization error either way
        # free: where the car can be now, cameras aside (the gate's question, on these
        # lanes); reach[j]: where it can be having crossed j watched-empty places. Only
        # a way that exists without the cameras and not with them is evidence.
        free = (ca <= tol) | (ra <= tol)
        reach = [free] + [np.zeros(len(ca), bool) for _ in range(self.cfg.misses)]
        t_all = self._ft[lo:hi]
        t_prev = ta
        for t in np.unique(t_all):
            at = np.flatnonzero(t_all == t) + lo
            can = (cb <= max_speed_mps * (tb - t) + tol) | end  # b still reachable in time
            step_m = max_speed_mps * (t - t_prev)
            free = self._expand(free, step_m) & can
            t_prev = t
            if not free.any():
                return True  # no way between them on these lanes: reachability's business
            moved = [self._expand(r, step_m) & can for r in reach]
            union = np.logical_or.reduce(moved)
            if not union.any():
                reach = moved
                continue
            idx = np.flatnonzero(union)
            empty = np.zeros(len(ca), bool)
            empty[idx[self._watched_empty(self._xy[idx], at)]] = True
            reach = [moved[0] & ~empty] + [(moved[j] & ~empty) | (moved[j - 1] & empty)
                                          for j in range(1, len(moved))]
        last_m = max_speed_mps * (tb - t_prev)
        if not (self._expand(free, last_m) & end).any():
            return True  # no way at all: not the cameras' evidence
        return bool((self._expand(np.logical_or.reduce(reach), last_m) & end).any())

    def _watched_empty(self, pts: np.ndarray, frames: np.ndarray) -> np.ndarray:
        """Per point of `pts`: watched and empty in one of these frames (one per camera
        at one moment), bool (N,)."""
        cfg = self.cfg
        out = np.zeros(len(pts), bool)
        for f in frames:
            v = self.views[int(self._fcam[f])]
            i = int(self._fidx[f])
            dx, dy = pts[:, 0] - v.x[i], pts[:, 1] - v.y[i]
            d = np.hypot(dx, dy)
            bear = (np.degrees(np.arctan2(dy, dx)) - v.yaw_deg[i] + 180.0) % 360.0 - 180.0
            see = ~out & (d >= cfg.near_m) & (d <= cfg.range_m) & \
                (np.abs(bear) <= v.fov_deg / 2.0 - cfg.fov_margin_deg)
            if not see.any():
                continue
            boxes = v.boxes[i]
            idx = np.flatnonzero(see)
            if len(boxes):
                covered = ((bear[idx, None] >= boxes[None, :, 0] - cfg.box_margin_deg)
                           & (bear[idx, None] <= boxes[None, :, 1] + cfg.box_margin_deg)).any(1)
                idx = idx[~covered]
            if len(idx):
                out[idx[self._clear(v.x[i], v.y[i], pts[idx])]] = True
        return out

    def _clear(self, cx: float, cy: float, pts: np.ndarray) -> np.ndarray:
        """Whether each sight line from (cx, cy) to a point stays over open ground."""
        d = np.hypot(pts[:, 0] - cx, pts[:, 1] - cy)
        n = max(2, math.ceil(float(d.max())) + 1)
        f = np.linspace(0.0, 1.0, n)
        line = np.stack([cx + f[None, :] * (pts[:, 0:1] - cx),
                         cy + f[None, :] * (pts[:, 1:2] - cy)], axis=-1).reshape(-1, 2)
        dist, _ = self._open.query(line, distance_upper_bound=self.cfg.open_m + 1e-9)
        return np.isfinite(dist).reshape(len(pts), n).all(axis=1)


__all__ = ["CameraViews", "Watch", "WatchConfig", "WatchError", "box_bearings"]
