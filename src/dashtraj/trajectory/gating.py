"""Spatio-temporal gating of re-identified tracks on the road network.

The paper accepts every gallery match whose appearance distance is small enough
and lists "spatio-temporal constraints" as future work (§V). This module is that
constraint: among candidate tracks of the target (each an observer's track whose
appearance matched), keep the largest set the target could physically have
produced, driving on the lane graph at a plausible speed.

The rule (`gate_tracks`):

1. **Reachability of one pair.** Track B can follow track A when, from A's last
   sighting at or before B's first sighting (time ``t_a``, position ``p_a``), the
   target could drive to B's first sighting (``t_b``, ``p_b``) in time::

       route_cost(p_a → p_b)  ≤  max_speed_mps · (t_b − t_a) + slack_m

   and, when the two tracks overlap in time, the same from B back to A's last
   sighting (both tracks describe one car at once, so each must be able to reach
   the other). Two tracks of one observer that were both seen at one moment more
   than ``same_camera_m`` apart (the other's position interpolated between its
   sightings) are two vehicles (its tracker kept them apart in the same frames), so
   never both the target. Two tracks of one observer seen at
   one moment at (nearly) one place are one vehicle seen twice: a duplicate box (a
   second orientation class that class-aware NMS keeps) or a track restarted while
   the old one still coasted; they are judged by reachability like any pair.
   The caller may also name pairs known to be two vehicles from the pixels
   (`apart`: two tracks of one camera with separate boxes in the same frames,
   `dashtraj.reidentify.select.box_relations`), which the sightings cannot
   show when one of the two was too far from the camera to be kept as a sighting,
   and pairs known to be one vehicle (`together`: overlapping boxes in the same
   frames), which the same-camera rule above then leaves to reachability.
   A sighting at most ``slack_m`` *behind* the other along the lanes
   counts as reachable (cost 0): localization jitter, not a loop around the block.
   ``route_cost`` is the lane graph's shortest route in metres with no lane-change
   penalty (a distance, not a preference). A localized position
   is ambiguous, so each sighting stands for several lane points and the cost is
   the least over all pairs of them:

   - every driving lane whose centre passes within `radius_m` of the estimated
     position (localization error),
   - the lane Algorithm 1 (`correct_position`) assigns from the seen orientation,
     and the lane of the other sign at the same road, section and s (the lane
     correction's own ambiguity: a front/back label read wrongly, or a position
     pushed across the road centre, must not make a true match look like a
     U-turn).

   A track that moved at least `heading_min_m` within `heading_window_s` of a
   sighting shows which way it drives there: that sighting's lane points are then
   only those whose driving direction is within 90° of the displacement (all of
   them if none is).
   So the gate is lenient by construction: it drops only candidates that are
   impossible under every reading of the positions; `slack_m` absorbs the
   remaining localization error at both ends.

2. **The consistent set** (``method="clique"``, the default). Every pair of the
   target's own tracks is reachable one from the other in time order (route costs
   obey the triangle inequality), so the target's tracks form a clique of the
   "reachable" graph over all candidate pairs. The clique of greatest total weight
   is kept (exact: `networkx.max_weight_clique`, a branch and bound; candidate
   sets after the appearance threshold are tens of tracks). A look-alike seen at
   the same time as one of the target's tracks, or anywhere the target could not
   be between two of its sightings, is dropped, whichever track comes first: one
   early false match cannot poison the rest, as it would a greedy filter ("keep a
   candidate when reachable from the last accepted one").
   ``method="chain"`` keeps the heaviest chain in which each *consecutive* pair is
   reachable (a longest path in the DAG, by dynamic programming, as a Viterbi pass
   with 0/−inf transitions): weaker, since a look-alike between two true tracks is
   checked against its neighbours only, not against a true track it overlaps.
   With an `anchor` (the track that holds the query crop, the target by definition)
   the best set *containing* the anchor is kept.

3. **One vehicle in several cameras** (``clique``). Two tracks of different observers
   that place their vehicle on (nearly) one spot at the same moments
   (`co_observed`, `GateConfig.co_observed_m`) show one car: it cannot be the target
   in one camera and a look-alike in the other, so they are kept or dropped together
   (one node of the clique problem, consistent with a track when every member is,
   weighing what they all weigh). A look-alike seen briefly by one camera, where the
   target could have been, and for longer by another, where it could not, goes whole.

Weights are the caller's: 1 per track (the most tracks), the track's sighting
count, or its ReID margin (threshold − distance). Ties go to the chain found first
in time order (deterministic).

Units: seconds, metres, metres per second; positions in CARLA world coordinates.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass

import numpy as np

from dashtraj.errors import DashtrajError
from dashtraj.roads import RoadMap, Waypoint
from dashtraj.trajectory.correction import _other_side_lane, correct_position
from dashtraj.trajectory.records import Sighting
from dashtraj.trajectory.watch import Watch


class GatingError(DashtrajError, ValueError):
    """Bad gating input: an empty track, a bad weight, an anchor out of range."""


GATE_METHODS: tuple[str, ...] = ("clique", "chain")
"""How `gate_tracks` picks the consistent tracks (module docstring)."""


@dataclass(frozen=True, slots=True)
class GateConfig:
    """Settings of the spatio-temporal gate.

    Attributes:
        max_speed_mps: the fastest plausible mean speed between two sightings, m/s.
            15 m/s = 54 km/h: above town streets' 30-50 km/h limits (CARLA's towns
            post 30 km/h; the built-in traffic drives at 9 m/s ± 15 %, an observer
            following the target at most 40 % faster), so a true match is never
            too fast; raise it for highways.
        slack_m: metres added to the reachable distance: the localization error
            of both sightings (the paper's noise is a few metres) and lane-centre
            snapping.
        radius_m: driving lanes within this distance of an estimated position are
            candidate lanes of that sighting, metres.
        heading_min_m: a track that moved this far within `heading_window_s` of a
            sighting keeps only lanes driving its way there, metres (inf: never).
        heading_window_s: half-width of that time window, seconds.
        same_camera_m: two tracks of one observer seen in one frame farther apart
            than this are two vehicles, metres (inf: never; 0: any two tracks of
            one observer that overlap in time, seen together or not, the rule
            before 2026-11-27). Two boxes of one vehicle are
            localized from nearly the same pixels; the nearest other vehicle is a
            lane (3.5 m) or a car length away.
        co_observed_m: two tracks of *different* observers whose positions at the
            same moments lie at most this far apart (the median over two or more
            moments) show one vehicle seen by two cameras: the gate (``clique``)
            keeps both or neither, metres (0: never). The same car cannot be the
            target in one camera and a look-alike in the other.
    """

    max_speed_mps: float = 15.0
    slack_m: float = 20.0
    radius_m: float = 5.0
    heading_min_m: float = 8.0
    heading_window_s: float = 3.0
    same_camera_m: float = 3.0
    co_observed_m: float = 2.5

    def __post_init__(self) -> None:
        for name in ("max_speed_mps", "slack_m", "radius_m", "heading_window_s"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise GatingError(f"GateConfig.{name} must be a finite number >= 0, got {v!r}")
        for name in ("heading_min_m", "same_camera_m", "co_observed_m"):
            h = getattr(self, name)
            if not (isinstance(h, int | float) and h >= 0 and not math.isnan(h)):
                raise GatingError(f"GateConfig.{name} must be a number >= 0, got {h!r}")


@dataclass(frozen=True, slots=True)
class GateResult:
    """The outcome of `gate_tracks`.

    Attributes:
        accepted: indices of the kept tracks (into the input), in time order.
        rejected: indices of the dropped tracks, ascending.
        weight: total weight of the kept tracks.
        order: all track indices in time order (first sighting, then index).
    """

    accepted: tuple[int, ...]
    rejected: tuple[int, ...]
    weight: float
    order: tuple[int, ...]


class _Lanes:
    """Candidate lane points of sightings, and route costs between them (cached)."""

    def __init__(self, road_map: RoadMap, config: GateConfig):
        self.map = road_map
        self.cfg = config
        self.graph = road_map.lane_graph(0.0)
        self._points: dict[tuple, list[Waypoint]] = {}

    def points(self, s: Sighting, heading: tuple[float, float] | None = None) -> list[Waypoint]:
        """Lane points of one sighting; with a heading (unit vector, CARLA world) only
        those of lanes driving within 90° of it (all when none does)."""
        key = (s, heading)
        hit = self._points.get(key)
        if hit is not None:
            return hit
        out: list[Waypoint] = []
        c = self.map.candidates((s.x, s.y), self.cfg.radius_m)
        out.extend(c.waypoints())
        corrected = correct_position(self.map, s).after
        out.append(corrected)
        other = _other_side_lane(self.map, corrected)
        if other is not None:
            out.append(self.map.waypoint(corrected.road_id, corrected.section_id, other,
                                         corrected.s))
        seen, unique = set(), []
        for wp in out:
            k = (wp.key, round(wp.s, 3))
            if k not in seen and wp.key in self.graph._length:
                seen.add(k)
                unique.append(wp)
        if heading is not None:
            hx, hy = heading
            ways = []
            for wp in unique:
                yaw = math.radians(wp.transform.rotation.yaw)
                if math.cos(yaw) * hx + math.sin(yaw) * hy > 0.0:
                    ways.append(wp)
            unique = ways or unique
        self._points[key] = unique
        return unique

    def cost(self, a: Sighting, b: Sighting, budget_m: float,
             heading_a: tuple[float, float] | None = None,
             heading_b: tuple[float, float] | None = None) -> float:
        """Least route cost from any lane point of a to any of b, metres (inf above budget)."""
        pa, pb = self.points(a, heading_a), self.points(b, heading_b)
        if not pa or not pb:
            return math.inf
        # The route is never shorter than the straight line between lane points.
        reach = 2.0 * self.cfg.radius_m + 10.0
        if math.hypot(a.x - b.x, a.y - b.y) - reach > budget_m:
            return math.inf
        best = math.inf
        for wa in pa:
            c = self.graph.route_costs(wa, pb, max_cost_m=budget_m)
            best = min(best, float(c.min()))
        if best > budget_m and self.cfg.slack_m > 0:
            # b at most slack_m *behind* a along the lanes: localization jitter, not a
            # loop around the block (the route from b forward to a is that short)
            for wb in pb:
                c = self.graph.route_costs(wb, pa, max_cost_m=self.cfg.slack_m)
                if float(c.min()) <= self.cfg.slack_m:
                    return 0.0
        return best


def reachable(road_map: RoadMap, a: Sighting, b: Sighting,
              config: GateConfig = GateConfig(), _lanes: _Lanes | None = None,
              heading_a: tuple[float, float] | None = None,
              heading_b: tuple[float, float] | None = None) -> bool:
    """Whether a vehicle seen at `a` could be seen at `b` (b.t >= a.t; see the module rule).

    Args:
        road_map: the map (CARLA world, metres).
        a, b: two sightings, a no later than b (seconds).
        config: speed, slack and lane radius.
        heading_a, heading_b: unit vectors (CARLA world) of the way each vehicle was
            seen driving, or None (any lane direction).

    Returns:
        True when the least route cost over the candidate lane points is at most
        ``max_speed_mps · (b.t − a.t) + slack_m``.

    Raises:
        GatingError: b is earlier than a.
    """
    if b.t < a.t:
        raise GatingError(f"reachable: b (t={b.t:g} s) is earlier than a (t={a.t:g} s)")
    lanes = _lanes if _lanes is not None else _Lanes(road_map, config)
    budget = config.max_speed_mps * (b.t - a.t) + config.slack_m
    return lanes.cost(a, b, budget, heading_a, heading_b) <= budget


def _heading(track: list[Sighting], at: Sighting, min_m: float,
             window_s: float) -> tuple[float, float] | None:
    """Unit vector of a track's displacement around one of its sightings: from the first
    to the last of its sightings within `window_s` seconds of it; None if that is
    shorter than `min_m` metres (a turn further along the track does not count)."""
    near = [s for s in track if abs(s.t - at.t) <= window_s]
    dx, dy = near[-1].x - near[0].x, near[-1].y - near[0].y
    n = math.hypot(dx, dy)
    return (dx / n, dy / n) if n >= min_m and n > 0 else None


def _position_at(track: list[Sighting], t: float,
                 max_gap_s: float = 1.0) -> tuple[float, float] | None:
    """A track's (time-ordered) position at time t: its own sighting then, or interpolated
    between two of its sightings at most `max_gap_s` apart (tracks are sampled on their
    own clocks); None outside them."""
    ts = [o.t for o in track]
    j = bisect.bisect_left(ts, t)
    if j < len(ts) and ts[j] - t <= 1e-3:
        return track[j].x, track[j].y
    if j > 0 and t - ts[j - 1] <= 1e-3:
        return track[j - 1].x, track[j - 1].y
    if 0 < j < len(ts) and ts[j] - ts[j - 1] <= max_gap_s:
        p, q = track[j - 1], track[j]
        f = (t - p.t) / (q.t - p.t)
        return p.x + f * (q.x - p.x), p.y + f * (q.y - p.y)
    return None


def co_observed(a_track: Sequence[Sighting], b_track: Sequence[Sighting], max_m: float,
                min_moments: int = 2) -> bool:
    """Whether two tracks of different observers show one vehicle: at `min_moments` or
    more of their sightings the other track's position at that moment (`_position_at`)
    is known, and the median distance between the two is at most `max_m` metres.

    Two cameras that see one car at once place it within their localization errors of
    each other (under a metre or two within 15 m); two different cars are a lane or a
    car length apart.
    """
    if max_m <= 0 or not a_track or not b_track \
            or a_track[0].observer_id == b_track[0].observer_id:
        return False
    a = sorted(a_track, key=lambda s: s.t)
    b = sorted(b_track, key=lambda s: s.t)
    if a[-1].t < b[0].t or b[-1].t < a[0].t:
        return False
    d = []
    for this, other in ((a, b), (b, a)):
        for s in this:
            p = _position_at(other, s.t)
            if p is not None:
                d.append(math.hypot(s.x - p[0], s.y - p[1]))
    return len(d) >= min_moments and float(np.median(d)) <= max_m


def _apart_at_once(a_track: list[Sighting], b_track: list[Sighting], max_m: float,
                   max_gap_s: float = 1.0) -> bool:
    """Whether two time-overlapping tracks of one camera (each in time order) are two
    vehicles: at some sighting of one, the other's position at that moment (its own
    sighting then, or interpolated between two of its sightings at most `max_gap_s`
    apart: tracks are sampled on their own clocks) is more than `max_m` metres away;
    always when `max_m` is 0. Tracks never seen together are not judged here."""
    if max_m == 0:
        return True
    for this, other in ((a_track, b_track), (b_track, a_track)):
        for s in this:
            p = _position_at(other, s.t, max_gap_s)
            if p is not None and math.hypot(s.x - p[0], s.y - p[1]) > max_m:
                return True
    return False


def _follows(road_map, lanes, cfg, a_track: list[Sighting], b_track: list[Sighting],
             one_vehicle: bool = False, watch: Watch | None = None) -> bool:
    """One car can have made both tracks, A starting no later than B (`one_vehicle`: the
    camera's pixels showed them as one vehicle, whatever their positions; `watch`: a
    `dashtraj.trajectory.watch.Watch`, and A ends before B starts: the drive between
    them must also be one the cameras could have missed)."""
    b0 = b_track[0]
    if (not one_vehicle and a_track[-1].t >= b0.t and a_track[0].observer_id == b0.observer_id
            and a_track[0].track_id != b0.track_id
            and _apart_at_once(a_track, b_track, cfg.same_camera_m)):
        return False  # one camera's two tracks seen apart at one moment: two vehicles
    def head(track, s):
        return _heading(track, s, cfg.heading_min_m, cfg.heading_window_s)

    a_ref = [s for s in a_track if s.t <= b0.t][-1]  # A starts first: never empty
    if not reachable(road_map, a_ref, b0, cfg, lanes, head(a_track, a_ref), head(b_track, b0)):
        return False
    a_last = a_track[-1]
    if watch is not None and a_last.t < b0.t and not watch.drive_unseen(
            a_last.t, lanes.points(a_last, head(a_track, a_last)), b0.t,
            lanes.points(b0, head(b_track, b0)), cfg.max_speed_mps, cfg.slack_m):
        return False  # every way between them led through watched, empty places
    if a_last.t > b0.t:  # overlap in time: B must reach A's last sighting too
        b_ref = [s for s in b_track if s.t <= a_last.t][-1]
        if not reachable(road_map, b_ref, a_last, cfg, lanes, head(b_track, b_ref),
                         head(a_track, a_last)):
            return False
    return True


def gate_tracks(road_map: RoadMap, tracks: Sequence[Sequence[Sighting]], *,
                weights: Sequence[float] | None = None, anchor: int | None = None,
                config: GateConfig = GateConfig(), method: str = "clique",
                apart: Collection[tuple[int, int]] = (),
                together: Collection[tuple[int, int]] = (),
                start_t: float | None = None, watch: Watch | None = None) -> GateResult:
    """Keep the heaviest set of candidate tracks one vehicle could have produced.

    Args:
        road_map: the map (CARLA world, metres).
        tracks: candidate tracks of the target, each a non-empty sequence of
            `Sighting` (any order within a track; one sighting is a track of one).
        weights: one weight (>= 0, finite) per track; None: 1 each.
        anchor: index of a track that must be kept (the query's own track), or None.
        config: `GateConfig`.
        method: "clique" (every pair consistent) or "chain" (consecutive pairs);
            see the module docstring.
        apart: pairs (i, j) of track indices known to be two vehicles (never both
            kept), whatever their positions say.
        together: pairs (i, j) of one camera's tracks known to be one vehicle seen
            twice: never called two vehicles for being seen apart at one moment
            (`GateConfig.same_camera_m`); still judged by reachability.
        start_t: the time of the target's first sighting (the query's), seconds, or
            None: a track whose sightings all come before it (other than the anchor)
            is another vehicle, rejected whatever else it fits (the route is rebuilt
            from the first sighting on).
        watch: a `dashtraj.trajectory.watch.Watch` (where the cameras looked and saw
            nothing), or None: a track that ends before another starts is the same car
            only if the drive between them could have gone unseen (`Watch.drive_unseen`).

    Returns:
        `GateResult` (accepted indices in time order, rejected indices).

    Raises:
        GatingError: an empty track, a weight that is negative or not finite, the
            wrong number of weights, an anchor or an `apart` / `together` index out of
            range, an unknown method.

    Example:
        >>> r = gate_tracks(town01, [track_a, twin_track, track_b])  # doctest: +SKIP
        >>> r.accepted, r.rejected  # doctest: +SKIP
        ((0, 2), (1,))
    """
    if method not in GATE_METHODS:
        raise GatingError(f"unknown gating method {method!r}; valid: {', '.join(GATE_METHODS)}")
    n = len(tracks)
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (n,):
        raise GatingError(f"gate_tracks: {n} tracks but {w.size} weights")
    if n and not (np.isfinite(w).all() and (w >= 0).all()):
        bad = int(np.flatnonzero(~(np.isfinite(w) & (w >= 0)))[0])
        raise GatingError(f"gate_tracks: weight {bad} must be finite and >= 0, got {w[bad]!r}")
    if anchor is not None and not 0 <= anchor < n:
        raise GatingError(f"gate_tracks: anchor {anchor} is not a track index (0..{n - 1})")
    two, one = set(), set()
    for name, pairs, into in (("apart", apart, two), ("together", together, one)):
        for pair in pairs:
            i, j = (int(v) for v in pair)
            if not (0 <= i < n and 0 <= j < n):
                raise GatingError(f"gate_tracks: {name} pair {tuple(pair)} is not two track "
                                  f"indices (0..{n - 1})")
            into.update(((i, j), (j, i)))
    ts: list[list[Sighting]] = []
    for i, tr in enumerate(tracks):
        if len(tr) == 0:
            raise GatingError(f"gate_tracks: track {i} has no sightings")
        ts.append(sorted(tr, key=lambda s: s.t))
    if n == 0:
        return GateResult((), (), 0.0, ())
    order = sorted(range(n), key=lambda i: (ts[i][0].t, i))
    if start_t is not None:
        keep = [i for i in range(n) if i == anchor or ts[i][-1].t >= start_t]
        if len(keep) < n:  # gate the others alone; the early ones are rejected
            at = {i: j for j, i in enumerate(keep)}
            sub = gate_tracks(road_map, [ts[i] for i in keep], weights=w[keep],
                              anchor=None if anchor is None else at[anchor], config=config,
                              method=method,
                              apart=[(at[i], at[j]) for i, j in two if i in at and j in at],
                              together=[(at[i], at[j]) for i, j in one
                                        if i in at and j in at], watch=watch)
            accepted = tuple(keep[j] for j in sub.accepted)
            return GateResult(accepted, tuple(sorted(set(range(n)) - set(accepted))),
                              sub.weight, tuple(order))
    lanes = _Lanes(road_map, config)
    ok = np.zeros((n, n), dtype=bool)  # ok[p, q]: order[q] can follow order[p]
    for q in range(n):
        for p in range(q):
            pair = (order[p], order[q])
            ok[p, q] = pair not in two and _follows(road_map, lanes, config, ts[order[p]],
                                                    ts[order[q]], one_vehicle=pair in one,
                                                    watch=watch)
    wo = w[order]
    if method == "clique":
        a_pos = None if anchor is None else order.index(anchor)
        sym = ok | ok.T  # consistent pairs, either order
        groups = _co_observed_groups(ts, order, sym, config.co_observed_m)
        chain = _best_clique(*_collapse(ok, sym, wo, groups, a_pos), a_pos)
        for g in groups:  # a group's members stand or fall with its first (or the anchor)
            if set(g) & set(chain):
                chain = sorted(set(chain) | set(g))
        accepted = tuple(order[j] for j in chain)
        rejected = tuple(sorted(set(range(n)) - set(accepted)))
        return GateResult(accepted, rejected, float(wo[chain].sum()), tuple(order))
    # forward: best chain ending at q; backward: best chain starting at q
    fwd, fprev = wo.copy(), np.full(n, -1)
    for q in range(n):
        for p in range(q):
            if ok[p, q] and fwd[p] + wo[q] > fwd[q]:
                fwd[q], fprev[q] = fwd[p] + wo[q], p
    bwd, bnext = wo.copy(), np.full(n, -1)
    for p in range(n - 1, -1, -1):
        for q in range(p + 1, n):
            if ok[p, q] and bwd[q] + wo[p] > bwd[p]:
                bwd[p], bnext[p] = bwd[q] + wo[p], q
    if anchor is None:
        k = int(np.argmax(fwd))  # first maximum: earliest end on a tie
        chain, j = [], k
        while j >= 0:
            chain.append(j)
            j = int(fprev[j])
        chain.reverse()
    else:
        k = order.index(anchor)
        head, j = [], int(fprev[k])
        while j >= 0:
            head.append(j)
            j = int(fprev[j])
        tail, j = [], int(bnext[k])
        while j >= 0:
            tail.append(j)
            j = int(bnext[j])
        chain = [*reversed(head), k, *tail]
    accepted = tuple(order[j] for j in chain)
    rejected = tuple(sorted(set(range(n)) - set(accepted)))
    return GateResult(accepted, rejected, float(wo[chain].sum()), tuple(order))


def _co_observed_groups(ts: list[list[Sighting]], order: list[int], sym: np.ndarray,
                        max_m: float) -> list[list[int]]:
    """Positions (time order) of the tracks that show one vehicle to several cameras
    (`co_observed`, and consistent by the gate), grouped; groups of two or more whose
    members are all consistent with one another."""
    n = len(order)
    parent = list(range(n))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    if max_m > 0:
        for q in range(n):
            for p in range(q):
                if sym[p, q] and co_observed(ts[order[p]], ts[order[q]], max_m):
                    parent[root(q)] = root(p)
    groups: dict[int, list[int]] = {}
    for j in range(n):
        groups.setdefault(root(j), []).append(j)
    # a chain of pairwise links whose ends the gate calls two vehicles is no one vehicle:
    # such a group is left to the gate track by track
    return [g for g in groups.values()
            if len(g) > 1 and all(sym[p, q] for p in g for q in g if p != q)]


def _collapse(ok: np.ndarray, sym: np.ndarray, w: np.ndarray, groups: list[list[int]],
              anchor: int | None) -> tuple[np.ndarray, np.ndarray]:
    """`ok` and weights with each group reduced to one track (the anchor if it is a member,
    else the first): consistent with another track when every member is, weighing what
    they all weigh; the other members drop out of the problem (weight 0, no pairs)."""
    if not groups:
        return ok, w
    ok2, w2 = ok.copy(), w.copy()
    for g in groups:
        r = anchor if anchor in g else g[0]
        both = sym[g].all(axis=0)
        for k in range(len(w)):
            if k not in g:
                ok2[min(r, k), max(r, k)] = both[k]
        for m in g:
            if m != r:
                ok2[m, :] = False
                ok2[:, m] = False
                w2[m] = 0.0
        w2[r] = float(w[g].sum())
    return ok2, w2


def _best_clique(ok: np.ndarray, w: np.ndarray, anchor: int | None) -> list[int]:
    """Positions (time order) of the heaviest set whose every pair is consistent.

    `ok[p, q]` (p < q) says positions p and q are consistent. Weights are scaled to
    integers (1e-6 resolution) for `networkx.max_weight_clique`; nodes are added in
    time order, so the answer is deterministic.
    """
    import networkx as nx

    n = len(w)
    nodes = range(n) if anchor is None else \
        [j for j in range(n) if j != anchor and (ok[min(j, anchor), max(j, anchor)])]
    g = nx.Graph()
    for j in nodes:
        g.add_node(j, weight=round(float(w[j]) * 1e6))
    for p in nodes:
        for q in nodes:
            if p < q and ok[p, q]:
                g.add_edge(p, q)
    best, _ = nx.max_weight_clique(g, weight="weight") if len(g) else ([], 0)
    if anchor is not None:
        best = [*best, anchor]
    if not best:  # every weight 0 and no anchor: the first track alone
        best = [0]
    return sorted(best)
