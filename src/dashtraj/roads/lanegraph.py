"""The directed lane graph and shortest routes on it (A*, metres).

Nodes are lanes (road_id, section_id, lane_id) of the routable type (Driving by
default). Edges, each with a `weight` in metres:

- ``follow``: lane A → every successor lane S, weight = A's centre-line length
  (the cost of driving A from its start to its end; plus its turn cost, below).
  Every lane-to-lane link of the map is kept, unlike CARLA's GlobalRoutePlanner,
  whose node keys (positions rounded to 1 m) make parallel edges overwrite each
  other.
- ``lane_change``: A → an adjacent lane B of the same section and direction,
  weight = ``lane_change_cost_m`` + the distance between the two lanes' start
  points. A lane change has a real cost, not zero as in CARLA's router.

A node's cost g is the cost of reaching its start point. A route from a point
on lane a (progress p_a along it) to a point on lane b (progress p_b) costs
(L_a − p_a) + Σ edges + p_b, or p_b − p_a when b lies ahead on a itself.

With ``turn_cost_m_per_rad`` k > 0, driving a stretch of lane costs its length
plus k times the heading change along it (the sum of |Δheading| over the
centre-line samples, radians): a route-choice prior that drivers prefer fewer
and gentler turns (turn penalties are standard in route-choice models). Lane
progress p is then replaced by the cost coordinate q(p) = p + k · turn(0..p) in
every formula above; lengths and polylines are unchanged. k = 0 (the default)
is the plain length.

The A* heuristic is the straight-line distance from a lane's start point to the
destination, less a 1 m slack for lane links that do not quite touch in real
maps. Every edge weight is at least the straight-line distance between the
start points it joins, so the heuristic is admissible and the routes are the
shortest in the graph (the tests check them against Dijkstra).
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import networkx as nx
import numpy as np

from dashtraj.errors import NoRouteError
from dashtraj.roads.types import LaneType, as_xyz

if TYPE_CHECKING:
    from dashtraj.roads.map import LaneKey, RoadMap, Waypoint

HEURISTIC_SLACK_M = 1.0


@dataclass(frozen=True, slots=True)
class RouteLeg:
    """A stretch of one lane: road s from `s_from` to `s_to` in its driving direction.

    `lane_change` is True when the route entered this lane by changing lanes.
    """

    key: tuple[int, int, int]
    s_from: float
    s_to: float
    lane_change: bool = False


@dataclass(frozen=True, slots=True)
class Route:
    """A route on the lane graph.

    `polyline` is (N, 2), CARLA world, metres, in driving order; `length_m` its
    length; `cost_m` the graph cost (length plus lane-change penalties, plus the
    turn costs when the graph has a `turn_cost_m_per_rad`).
    """

    legs: tuple[RouteLeg, ...]
    polyline: np.ndarray
    length_m: float
    cost_m: float
    map: RoadMap = field(repr=False, compare=False)

    @property
    def waypoints(self) -> list[Waypoint]:
        """One waypoint at the start of each leg, then the destination."""
        from dashtraj.roads.map import Waypoint

        out = [Waypoint(*leg.key, leg.s_from, self.map) for leg in self.legs]
        last = self.legs[-1]
        out.append(Waypoint(*last.key, last.s_to, self.map))
        return out

    @property
    def lane_changes(self) -> int:
        return sum(leg.lane_change for leg in self.legs)


class LaneGraph:
    """Directed graph over the lanes of a `RoadMap`, for routing in metres.

    Args:
        road_map: the map.
        lane_change_cost_m: penalty of one lane change, metres-equivalent.
        lane_type: the lanes that may be driven.
        turn_cost_m_per_rad: metres-equivalent cost of one radian of heading
            change along a lane (0: routes by length alone).
    """

    def __init__(self, road_map: RoadMap, lane_change_cost_m: float = 15.0,
                 lane_type: LaneType = LaneType.Driving, turn_cost_m_per_rad: float = 0.0):
        if lane_change_cost_m < 0:
            raise ValueError("lane_change_cost_m must be non-negative")
        if not (math.isfinite(turn_cost_m_per_rad) and turn_cost_m_per_rad >= 0):
            raise ValueError("turn_cost_m_per_rad must be a finite number >= 0")
        self.map = road_map
        self.lane_change_cost_m = float(lane_change_cost_m)
        self.turn_cost_m_per_rad = float(turn_cost_m_per_rad)
        self.lane_type = lane_type
        m = road_map
        self.graph = nx.DiGraph()
        self._length: dict[LaneKey, float] = {}
        self._start: dict[LaneKey, tuple[float, float]] = {}
        self._arc: dict[LaneKey, tuple[np.ndarray, np.ndarray]] = {}
        # Cost coordinate along the arc (road s order) and a lane's whole cost, with turns.
        self._carc: dict[LaneKey, np.ndarray] = {}
        self._clen: dict[LaneKey, float] = {}
        k_turn = self.turn_cost_m_per_rad
        for lane in m.lane_list:
            if not lane.type & lane_type:
                continue
            sl = slice(lane.v0, lane.v1)
            xy = np.column_stack([m._vx[sl], m._vy[sl]])
            step = np.diff(xy, axis=0)
            seg = np.linalg.norm(step, axis=1)
            arc = np.concatenate([[0.0], np.cumsum(seg)])
            self._arc[lane.key] = (m._vs[sl], arc)
            length = float(arc[-1])
            if k_turn > 0:
                carc = arc + k_turn * _turn_along(step, seg)
                self._carc[lane.key] = carc
                self._clen[lane.key] = float(carc[-1])
            else:
                self._clen[lane.key] = length
            start = xy[0] if lane.forward else xy[-1]
            self._length[lane.key] = length
            self._start[lane.key] = (float(start[0]), float(start[1]))
            self.graph.add_node(lane.key, length=length, cost=self._clen[lane.key],
                                start=self._start[lane.key])
        for key in self._length:
            lane = m.lanes[key]
            for t in lane.successors:
                if t in self._length:
                    self.graph.add_edge(key, t, weight=self._clen[key], kind="follow")
            for nb in self._neighbours(key):
                gap = math.dist(self._start[key], self._start[nb])
                self.graph.add_edge(key, nb, weight=self.lane_change_cost_m + gap,
                                    kind="lane_change")
        self._adj = {u: [(v, d["weight"], d["kind"] == "lane_change")
                         for v, d in self.graph[u].items()] for u in self.graph}

    def _neighbours(self, key: LaneKey) -> list[LaneKey]:
        rid, sec, lid = key
        out = []
        for nid in (lid - 1, lid + 1):
            if nid == 0 or (nid > 0) != (lid > 0):
                continue
            nk = (rid, sec, nid)
            if nk in self._length:
                out.append(nk)
        return out

    # ------------------------------------------------------------------ progress
    def progress(self, key: LaneKey, s: float) -> float:
        """Metres along lane `key`'s centre from its start (driving direction) to road s."""
        ss, arc = self._arc[key]
        a = float(np.interp(s, ss, arc))
        return a if key[2] < 0 else float(arc[-1] - a)

    def cost_at(self, key: LaneKey, s: float) -> float:
        """The cost coordinate q at road s: metres from the lane's start (driving
        direction) plus ``turn_cost_m_per_rad`` × the heading change on the way."""
        if self.turn_cost_m_per_rad == 0:
            return self.progress(key, s)
        ss, _ = self._arc[key]
        c = float(np.interp(s, ss, self._carc[key]))
        return c if key[2] < 0 else self._clen[key] - c

    def _goal(self, key: LaneKey, s: float) -> tuple[LaneKey, float, float]:
        """(lane, progress, cost coordinate) at road s: one interpolation when the graph
        has no turn cost (the two are equal then)."""
        p = self.progress(key, s)
        return key, p, (p if self.turn_cost_m_per_rad == 0 else self.cost_at(key, s))

    def s_at_progress(self, key: LaneKey, p: float) -> float:
        ss, arc = self._arc[key]
        a = p if key[2] < 0 else arc[-1] - p
        return float(np.interp(a, arc, ss))

    def _start_entries(self, wp: Waypoint) -> list[tuple[LaneKey, float, float, float, list]]:
        """(lane, entry progress, entry cost coordinate, cost so far, path) for the origin
        and lane changes from it."""
        if wp.key not in self._length:
            raise NoRouteError(f"{self.map.name}: origin {wp} is not on a routable lane")
        out = [(*self._goal(wp.key, wp.s), 0.0, [wp.key])]
        seen = {wp.key}
        i = 0
        while i < len(out):
            key, _, _, cost, path = out[i]
            i += 1
            for nb in self._neighbours(key):
                if nb in seen:
                    continue
                seen.add(nb)
                gap = math.dist(self._point(key, wp.s), self._point(nb, wp.s))
                out.append((*self._goal(nb, wp.s), cost + self.lane_change_cost_m + gap,
                            [*path, nb]))
        return out

    def _point(self, key: LaneKey, s: float) -> tuple[float, float]:
        x, y = self._points_at(key, np.array([s]))[0]
        return float(x), float(y)

    # ------------------------------------------------------------------ search
    def _search(self, origin: Waypoint, goals: list[tuple[LaneKey, float, float]],
                target_xy: tuple[float, float] | None, max_cost_m: float = math.inf):
        """A* (one goal, heuristic towards target_xy) or Dijkstra (target_xy None).

        `goals` are (lane, progress, cost coordinate) triples.

        Returns (best cost per goal, back-pointer data for path recovery).
        """
        best = [math.inf] * len(goals)
        best_how: list = [None] * len(goals)
        goal_at: dict[LaneKey, list[int]] = {}
        for gi, (k, _, _) in enumerate(goals):
            goal_at.setdefault(k, []).append(gi)
        tx, ty = target_xy if target_xy is not None else (0.0, 0.0)

        def h(key):
            if target_xy is None:
                return 0.0
            sx, sy = self._start[key]
            return max(0.0, math.hypot(sx - tx, sy - ty) - HEURISTIC_SLACK_M)

        g: dict[LaneKey, float] = {}
        parent: dict[LaneKey, tuple] = {}
        heap: list = []
        for key, p_entry, q_entry, cost, path in self._start_entries(origin):
            for gi in goal_at.get(key, ()):
                _, pg, qg = goals[gi]
                if pg >= p_entry - 1e-9 and cost + qg - q_entry < best[gi]:
                    best[gi] = cost + qg - q_entry
                    best_how[gi] = ("direct", path, p_entry)
            exit_cost = cost + self._clen[key] - q_entry
            for nxt, _, is_lc in self._adj[key]:
                if is_lc:
                    continue
                if exit_cost < g.get(nxt, math.inf):
                    g[nxt] = exit_cost
                    parent[nxt] = ("start", path, p_entry)
                    heapq.heappush(heap, (exit_cost + h(nxt), exit_cost, nxt))
        closed = set()
        while heap:
            f, gk, key = heapq.heappop(heap)
            if gk > g.get(key, math.inf) or key in closed:
                continue
            if f >= max(best) or gk > max_cost_m:
                break
            closed.add(key)
            for gi in goal_at.get(key, ()):
                c = gk + goals[gi][2]
                if c < best[gi]:
                    best[gi] = c
                    best_how[gi] = ("node", key)
            for nxt, w, _ in self._adj[key]:
                ng = gk + w
                if ng < g.get(nxt, math.inf):
                    g[nxt] = ng
                    parent[nxt] = ("node", key)
                    heapq.heappush(heap, (ng + h(nxt), ng, nxt))
        return best, best_how, parent

    def route(self, origin, destination) -> Route:
        """The shortest route from one location to another.

        Args:
            origin, destination: `Waypoint`, `Location`, carla.Location or (x, y);
                CARLA world, metres. Locations are projected to the nearest lane
                of the graph's lane type.

        Returns:
            `Route` with legs, polyline (N, 2), length and cost in metres.

        Raises:
            NoRouteError: the destination cannot be reached from the origin.

        Example:
            >>> r = road_map.lane_graph().route((10, 2), (120, 60))  # doctest: +SKIP
            >>> round(r.length_m, 1)  # doctest: +SKIP
        """
        a = self._as_waypoint(origin)
        b = self._as_waypoint(destination)
        if b.key not in self._length:
            raise NoRouteError(f"{self.map.name}: destination {b} is not on a routable lane")
        best, how, parent = self._search(a, [self._goal(b.key, b.s)], self._start_xy_of(b))
        if not math.isfinite(best[0]):
            raise NoRouteError(
                f"{self.map.name}: no route from road {a.road_id} lane {a.lane_id} s={a.s:.1f} "
                f"to road {b.road_id} lane {b.lane_id} s={b.s:.1f} on the lane graph"
            )
        legs = self._legs(a, b, how[0], parent)
        poly = self._polyline(legs)
        length = float(np.sum(np.linalg.norm(np.diff(poly, axis=0), axis=1))) if len(poly) > 1 \
            else 0.0
        return Route(tuple(legs), poly, length, float(best[0]), self.map)

    def route_cost(self, origin, destination, max_cost_m: float = math.inf) -> float:
        """Cost in metres of the shortest route (inf when unreachable or above max)."""
        a = self._as_waypoint(origin)
        b = self._as_waypoint(destination)
        if b.key not in self._length:
            return math.inf
        best, _, _ = self._search(a, [self._goal(b.key, b.s)], self._start_xy_of(b),
                                  max_cost_m)
        return best[0] if best[0] <= max_cost_m else math.inf

    def route_costs(self, origin, destinations, max_cost_m: float = math.inf) -> np.ndarray:
        """Costs from one origin to many destinations (Dijkstra, one search), metres.

        Unreachable destinations, or those costing more than `max_cost_m`, get inf.
        """
        a = self._as_waypoint(origin)
        goals, idx = [], []
        for i, d in enumerate(destinations):
            b = self._as_waypoint(d)
            if b.key in self._length:
                goals.append(self._goal(b.key, b.s))
                idx.append(i)
        out = np.full(len(destinations), math.inf)
        if goals:
            best, _, _ = self._search(a, goals, None, max_cost_m)
            out[idx] = best
        out[out > max_cost_m] = math.inf
        return out

    def _start_xy_of(self, wp: Waypoint) -> tuple[float, float]:
        return self._point(wp.key, wp.s)

    def _as_waypoint(self, loc) -> Waypoint:
        from dashtraj.roads.map import Waypoint

        if isinstance(loc, Waypoint):
            return loc
        x, y, z = as_xyz(loc)  # a z makes the match height-aware (see RoadMap.project)
        return self.map.get_waypoint((x, y) if z is None else (x, y, z), lane_type=self.lane_type)

    # ------------------------------------------------------------------ route geometry
    def _legs(self, a: Waypoint, b: Waypoint, how, parent) -> list[RouteLeg]:
        lanes = self.map.lanes
        if how[0] == "direct":
            _, path, _ = how
            legs = [RouteLeg(k, a.s, a.s, lane_change=i > 0) for i, k in enumerate(path[:-1])]
            legs.append(RouteLeg(path[-1], a.s, b.s, lane_change=len(path) > 1))
            return legs
        # Walk back from the destination lane.
        chain: list[tuple[LaneKey, bool]] = []
        key = how[1]
        while parent[key][0] != "start":
            prev = parent[key][1]
            chain.append((key, any(n == key and lc for n, _, lc in self._adj[prev])))
            key = prev
        chain.append((key, False))
        chain.reverse()
        start_path = parent[key][1]
        legs = [RouteLeg(k, a.s, a.s, lane_change=i > 0) for i, k in enumerate(start_path[:-1])]
        last = start_path[-1]
        legs.append(RouteLeg(last, a.s, lanes[last].end_s, lane_change=len(start_path) > 1))
        for i, (k, lc) in enumerate(chain):
            if lc:
                # Changing lanes at a lane's start: the lane left behind is driven 0 m.
                prev = legs[-1]
                legs[-1] = RouteLeg(prev.key, prev.s_from, prev.s_from, prev.lane_change)
            s_to = b.s if i == len(chain) - 1 else lanes[k].end_s
            legs.append(RouteLeg(k, lanes[k].start_s, s_to, lane_change=lc))
        return legs

    def _points_at(self, key: LaneKey, s: np.ndarray) -> np.ndarray:
        """Lane-centre points at road s, interpolated between the exact samples (≤ 1 m)."""
        lane = self.map.lanes[key]
        sl = slice(lane.v0, lane.v1)
        vs = self.map._vs[sl]
        return np.column_stack([np.interp(s, vs, self.map._vx[sl]),
                                np.interp(s, vs, self.map._vy[sl])])

    def _leg_points(self, key: LaneKey, s_from: float, s_to: float):
        """Centre points of a leg in driving order: its ends and every sample between."""
        lane = self.map.lanes[key]
        lo, hi = (s_from, s_to) if s_from <= s_to else (s_to, s_from)
        vs = self.map._vs[lane.v0:lane.v1]
        i0, i1 = np.searchsorted(vs, [lo, hi], side="right")
        s = np.concatenate([[lo], vs[i0:i1][vs[i0:i1] < hi], [hi]])
        if not lane.forward:
            s = s[::-1]
        return self._points_at(key, s), s

    def _polyline(self, legs: list[RouteLeg]) -> np.ndarray:
        """Centre-line points of the legs; a lane change blends across over ≤ 20 m."""
        parts: list[np.ndarray] = []
        prev_key = None
        for leg in legs:
            pts, s = self._leg_points(leg.key, leg.s_from, leg.s_to)
            if leg.lane_change and prev_key is not None and prev_key[:2] == leg.key[:2]:
                prev_pts = self._points_at(prev_key, s)
                along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0),
                                                                        axis=1))])
                w = np.clip(along / min(20.0, max(along[-1], 1e-9)), 0.0, 1.0)[:, None]
                pts = (1 - w) * prev_pts + w * pts
            if abs(leg.s_to - leg.s_from) > 1e-9:
                parts.append(pts)
            prev_key = leg.key
        first, last = legs[0], legs[-1]
        parts.insert(0, self._points_at(first.key, np.array([first.s_from])))
        parts.append(self._points_at(last.key, np.array([last.s_to])))
        poly = np.concatenate(parts)
        keep = np.concatenate([[True], np.linalg.norm(np.diff(poly, axis=0), axis=1) > 1e-6])
        return poly[keep]


def _turn_along(step: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Cumulative heading change (radians) at each vertex of a polyline, from its steps
    (N, 2) and their lengths (N,).

    Vertex i gets the sum of |Δheading| between consecutive steps up to it; the
    change at a vertex is counted at that vertex. Zero-length steps are skipped.
    """
    n = len(step) + 1
    out = np.zeros(n)
    if n < 3:
        return out
    heading = np.arctan2(step[:, 1], step[:, 0])
    ok = seg > 1e-9
    idx = np.flatnonzero(ok)
    if len(idx) < 2:
        return out
    turn = np.abs((np.diff(heading[idx]) + math.pi) % (2 * math.pi) - math.pi)
    # the change between steps idx[j] and idx[j+1] happens at vertex idx[j+1]
    add = np.zeros(n)
    add[idx[1:]] = turn
    return np.cumsum(add)
