"""`RoadMap`: an OpenDRIVE road network answering CARLA's questions.

All inputs and outputs are in the CARLA world frame (metres; OpenDRIVE's y is
flipped; yaw in degrees along the lane's driving direction). A waypoint is
(road_id, section_id, lane_id, s) as in CARLA; see ``shared/CARLA_FACTS.md``.

The map samples every lane's centre line at most 1 m apart (exact positions and
headings at the samples) and indexes the sample segments with a k-d tree. A
query finds the nearest segment exactly (the candidate search grows until no
unseen segment can be nearer) and then refines the foot point on the cubic
Hermite curve through the segment's end samples, which is within micrometres of
the true lane centre.

Height (the z rule, CARLA's): a query that carries a z (a `Location`, a
carla.Location, an (x, y, z) tuple, or an (N, 3) array) picks the lane-centre
segment nearest in 3-D, i.e. by the Euclidean distance from (x, y, z) to the
3-D polyline of lane-centre samples (x, y and the road's elevation), exactly as
CARLA's ``Map::GetClosestWaypointOnRoad`` asks its R-tree of 3-D lane segments
for the nearest one to ``(x, y, z)``. The foot point on that segment is then the
plan-view (2-D) one, as CARLA's ``DistanceSegmentToPoint`` projects in 2-D. So a
point under a bridge maps to the road it is on, not to the bridge above. A query
with no z (an (x, y) tuple, an (N, 2) array, or z = NaN in a row of an (N, 3)
array) is matched in plan view only, as before.

Example:
    >>> m = RoadMap.from_file("Town10HD.xodr")  # doctest: +SKIP
    >>> wp = m.get_waypoint(Location(-41.0, 20.0))  # doctest: +SKIP
    >>> wp.road_id, wp.lane_id, round(wp.s, 2)  # doctest: +SKIP
"""

from __future__ import annotations

import contextlib
import gc
import hashlib
import math
import warnings
from bisect import bisect_left, bisect_right
from dataclasses import dataclass, field
from functools import partial
from itertools import chain, repeat
from operator import itemgetter
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from dashtraj.errors import OffRoadError
from dashtraj.roads.opendrive import (
    OpenDrive,
    OpenDriveWarning,
    RoadRecord,
    parse_opendrive,
    read_opendrive,
)
from dashtraj.roads.types import (
    LaneType,
    Location,
    Rotation,
    Transform,
    as_xyz,
    normalize_yaw,
)

LaneKey = tuple[int, int, int]  # (road_id, section_id, lane_id)


def _linspace(a: float, b: float, n: int) -> np.ndarray:
    """np.linspace(a, b, n) for n ≥ 2 without its overhead (endpoints exact)."""
    out = np.arange(n, dtype=float)
    out *= (b - a) / (n - 1)
    out += a
    out[-1] = b
    return out


def _hermite(p0, t0, p1, t1, tt):
    """Cubic Hermite curve through p0, p1 with tangents t0, t1, at parameters tt (N, 1).

    Returns the point, its first and its second derivative, each (N, 2).
    """
    tt2, tt3 = tt * tt, tt * tt * tt
    c = (p0 * (2 * tt3 - 3 * tt2 + 1) + t0 * (tt3 - 2 * tt2 + tt)
         + p1 * (-2 * tt3 + 3 * tt2) + t1 * (tt3 - tt2))
    c1 = (p0 * (6 * tt2 - 6 * tt) + t0 * (3 * tt2 - 4 * tt + 1)
          + p1 * (-6 * tt2 + 6 * tt) + t1 * (3 * tt2 - 2 * tt))
    c2 = p0 * (12 * tt - 6) + t0 * (6 * tt - 4) + p1 * (6 - 12 * tt) + t1 * (6 * tt - 2)
    return c, c1, c2


@contextlib.contextmanager
def _gc_paused():
    """Pause the cyclic garbage collector while building many long-lived objects.

    Reading a map allocates tens of thousands of small objects that all survive;
    the collector's passes over them are pure overhead (about 10 % of a load).
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()

SAMPLE_STEP_M = 1.0
_EPS = 10.0 * np.finfo(float).eps  # CARLA's EPSILON in Map::GenerateWaypoints


@dataclass(slots=True)
class Lane:
    """One lane of one lane section (internal; exposed for the lane graph and tools)."""

    key: LaneKey
    index: int
    type: LaneType
    type_name: str
    s0: float  # section start, road s, metres
    s1: float  # section end
    junction: int
    successors: list[LaneKey] = field(default_factory=list)
    predecessors: list[LaneKey] = field(default_factory=list)
    v0: int = 0  # first sample index in the map's sample arrays
    v1: int = 0  # one past the last sample index

    @property
    def road_id(self) -> int:
        return self.key[0]

    @property
    def section_id(self) -> int:
        return self.key[1]

    @property
    def lane_id(self) -> int:
        return self.key[2]

    @property
    def forward(self) -> bool:
        """True when the lane drives along increasing s (negative lane id)."""
        return self.key[2] < 0

    @property
    def start_s(self) -> float:
        """s at the start of the lane in its driving direction."""
        return self.s0 if self.forward else self.s1

    @property
    def end_s(self) -> float:
        return self.s1 if self.forward else self.s0


class Waypoint(tuple):
    """A point on a lane centre: CARLA's (road_id, section_id, lane_id, s).

    `s` is metres from the road start (reference line), whatever the lane's
    driving direction. The pose is computed exactly from the road geometry.

    An immutable record with fields `road_id`, `section_id`, `lane_id`, `s` and
    `map`; equality and hash use the first four only. It is a tuple underneath
    (so that maps build thousands of them at C speed, as `generate_waypoints`
    does), but treat it as a record: its fields are its interface.
    """

    __slots__ = ()

    def __new__(cls, road_id: int, section_id: int, lane_id: int, s: float, map: RoadMap):
        return tuple.__new__(cls, (road_id, section_id, lane_id, s, map))

    road_id: int = property(itemgetter(0), doc="OpenDRIVE road id.")  # type: ignore[assignment]
    section_id: int = property(itemgetter(1), doc="0-based lane section index.")  # type: ignore[assignment]
    lane_id: int = property(itemgetter(2), doc="Signed OpenDRIVE lane id.")  # type: ignore[assignment]
    s: float = property(itemgetter(3), doc="Metres from the road start.")  # type: ignore[assignment]
    map: RoadMap = property(itemgetter(4), doc="The map it lies on.")  # type: ignore[assignment]
    key: LaneKey = property(itemgetter(0, 1, 2),  # type: ignore[assignment]
                            doc="(road_id, section_id, lane_id).")

    def __eq__(self, other) -> bool:
        if other.__class__ is not Waypoint:
            return NotImplemented
        return self[:4] == other[:4]

    def __ne__(self, other) -> bool:
        if other.__class__ is not Waypoint:
            return NotImplemented
        return self[:4] != other[:4]

    def __hash__(self) -> int:
        return hash(self[:4])

    def __lt__(self, other):  # no ordering, as a record
        return NotImplemented

    __le__ = __gt__ = __ge__ = __lt__

    def __repr__(self) -> str:
        return (f"Waypoint(road_id={self[0]!r}, section_id={self[1]!r}, lane_id={self[2]!r}, "
                f"s={self[3]!r})")

    def __getnewargs__(self):
        return tuple(self)

    @property
    def lane(self) -> Lane:
        return self.map.lanes[self.key]

    @property
    def transform(self) -> Transform:
        """Lane-centre pose: location (m) and yaw (deg) along the driving direction."""
        x, y, z, yaw = self.map._lane_pose(self.key, np.array([self.s]))
        return Transform(Location(float(x[0]), float(y[0]), float(z[0])),
                         Rotation(0.0, float(yaw[0]), 0.0))

    @property
    def lane_width(self) -> float:
        return float(self.map._lane_width(self.key, np.array([self.s]))[0])

    @property
    def is_junction(self) -> bool:
        return self.map.roads[self.road_id].junction != -1

    @property
    def junction_id(self) -> int:
        return self.map.roads[self.road_id].junction

    @property
    def lane_type(self) -> LaneType:
        return self.lane.type

    @property
    def id(self) -> int:
        """A stable integer id of (road, section, lane, s to the centimetre)."""
        h = hashlib.blake2b(
            f"{self.road_id}/{self.section_id}/{self.lane_id}/{round(self.s, 2):.2f}".encode(),
            digest_size=8,
        )
        return int.from_bytes(h.digest(), "little") >> 1

    def next(self, distance: float) -> list[Waypoint]:
        """Waypoints `distance` metres ahead along the driving direction.

        Past the lane's end the walk continues into every successor lane, so the
        list can hold several waypoints (a junction ahead), or none (a dead end).
        Distances are measured in road s, as CARLA does.

        Raises:
            ValueError: distance is not positive.
        """
        return self.map._walk(self, distance, forward=True)

    def previous(self, distance: float) -> list[Waypoint]:
        """Waypoints `distance` metres behind, mirroring `next`."""
        return self.map._walk(self, distance, forward=False)

    def next_until_lane_end(self, distance: float) -> list[Waypoint]:
        """Waypoints every `distance` metres from here to the end of this lane."""
        lane = self.lane
        step = distance if lane.forward else -distance
        out = []
        s = self.s + step
        while (s <= lane.s1) if lane.forward else (s >= lane.s0):
            out.append(self.map.waypoint(*self.key, s))
            s += step
        return out

    def get_left_lane(self) -> Waypoint | None:
        """The lane to the left of the driving direction at the same s (any type), or None."""
        return self.map._side_lane(self, left=True)

    def get_right_lane(self) -> Waypoint | None:
        """The lane to the right of the driving direction at the same s (any type), or None."""
        return self.map._side_lane(self, left=False)


@dataclass(frozen=True, slots=True)
class LaneProjection:
    """The vectorised answer of `RoadMap.project`: one row per query point.

    Arrays, all (N,): `road_id`, `section_id`, `lane_id` (int), `s` (m from road
    start), `x`, `y`, `z` (lane-centre point, CARLA world, m), `yaw` (deg, driving
    direction), `lateral_m` (signed offset of the query from the centre, positive to
    the right of the driving direction), `distance_m` (distance from the query to the
    lane-centre point: plan-view, or 3-D for a query that carries a z), `lane_width`
    (m), `lane_index` (index into `RoadMap.lane_list`).
    """

    road_id: np.ndarray
    section_id: np.ndarray
    lane_id: np.ndarray
    s: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    yaw: np.ndarray
    lateral_m: np.ndarray
    distance_m: np.ndarray
    lane_width: np.ndarray
    lane_index: np.ndarray
    map: RoadMap = field(repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.s)

    @property
    def inside(self) -> np.ndarray:
        """True where the query lies within half a lane width of the centre line."""
        return np.abs(self.lateral_m) <= 0.5 * self.lane_width + 1e-9

    def waypoint(self, i: int) -> Waypoint:
        return Waypoint(int(self.road_id[i]), int(self.section_id[i]), int(self.lane_id[i]),
                        float(self.s[i]), self.map)

    def waypoints(self) -> list[Waypoint]:
        make, m = tuple.__new__, self.map
        return [make(Waypoint, (r, k, lane, s, m)) for r, k, lane, s in
                zip(self.road_id.tolist(), self.section_id.tolist(), self.lane_id.tolist(),
                    self.s.tolist(), strict=True)]


@dataclass(frozen=True, slots=True)
class LaneSamples:
    """Centre-line samples of one lane; see `RoadMap.lane_samples`."""

    s: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    heading: np.ndarray
    width: np.ndarray


class RoadMap:
    """A road network read from OpenDRIVE, queried like `carla.Map`.

    Build with `RoadMap.from_file(path)` or `RoadMap.from_string(text)`.
    """

    def __init__(self, od: OpenDrive, sample_step_m: float = SAMPLE_STEP_M):
        self.opendrive = od
        self.name = od.name
        self.roads: dict[int, RoadRecord] = od.roads
        self.junctions = od.junctions
        self.sample_step_m = float(sample_step_m)
        self.lanes: dict[LaneKey, Lane] = {}
        self.lane_list: list[Lane] = []
        self._build_lanes()
        self._link_lanes()
        self._sample_lanes()
        self._trees: dict[int, tuple[cKDTree, np.ndarray, float]] = {}
        self._graphs: dict = {}

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_file(cls, path: str | Path, **kw) -> RoadMap:
        """Read and index an OpenDRIVE file. Raises `OpenDriveError` if it is not one."""
        with _gc_paused():
            m = cls(read_opendrive(path), **kw)
        m.path = Path(path)
        return m

    @classmethod
    def from_string(cls, text: str | bytes, name: str = "<string>", **kw) -> RoadMap:
        with _gc_paused():
            m = cls(parse_opendrive(text, name=name), **kw)
        m.path = None
        return m

    path: Path | None = None

    def _build_lanes(self) -> None:
        driving = LaneType.Driving
        # Per road, for generate_waypoints: (id, length, section starts, Driving lane
        # ids of each section in id order).
        self._road_driving: list[tuple[int, float, list[float], list[list[int]]]] = []
        for road in self.roads.values():
            per_section = []
            for k, sec in enumerate(road.sections):
                s1 = road.section_ends[k]
                ids = []
                for lid in sorted(sec.lanes):
                    rec = sec.lanes[lid]
                    lane = Lane((road.id, k, lid), len(self.lane_list),
                                LaneType.from_opendrive(rec.type), rec.type, sec.s, s1,
                                road.junction)
                    self.lanes[lane.key] = lane
                    self.lane_list.append(lane)
                    if lane.type == driving:
                        ids.append(lid)
                per_section.append(ids)
            self._road_driving.append((road.id, float(road.length),
                                       [sec.s for sec in road.sections], per_section))

    def _section_of(self, road: RoadRecord, contact: str | None) -> int:
        return 0 if contact == "start" else len(road.sections) - 1

    def _link_lanes(self) -> None:
        """Successor lanes in the driving direction, as CARLA's MapBuilder links them."""
        name = self.name
        # Junction connections grouped by incoming road.
        incoming: dict[tuple[int, int], list] = {}
        for j in self.junctions.values():
            for c in j.connections:
                incoming.setdefault((j.id, c.incoming_road), []).append(c)

        def lane_or_warn(road_id: int, section: int, lane_id: int, where: str) -> LaneKey | None:
            key = (road_id, section, lane_id)
            if key not in self.lanes:
                warnings.warn(f"{name}: {where} links to lane {lane_id} of road {road_id} "
                              f"section {section}, which does not exist; link ignored",
                              OpenDriveWarning, stacklevel=3)
                return None
            return key

        for lane in self.lane_list:
            rid, k, lid = lane.key
            road = self.roads[rid]
            rec = road.sections[k].lanes[lid]
            forward = lid < 0
            where = f"road {rid} section {k} lane {lid}"
            link_id = rec.successor if forward else rec.predecessor
            last = len(road.sections) - 1
            targets: list[LaneKey] = []
            if (forward and k < last) or (not forward and k > 0):
                if link_id is not None:
                    t = lane_or_warn(rid, k + 1 if forward else k - 1, link_id, where)
                    if t:
                        targets.append(t)
            else:
                rlink = road.successor if forward else road.predecessor
                if rlink is not None and rlink.element_type == "road":
                    if link_id is not None and rlink.element_id in self.roads:
                        other = self.roads[rlink.element_id]
                        t = lane_or_warn(other.id, self._section_of(other, rlink.contact_point),
                                         link_id, where)
                        if t:
                            targets.append(t)
                elif rlink is not None and rlink.element_type == "junction":
                    for c in incoming.get((rlink.element_id, rid), ()):
                        if c.connecting_road not in self.roads:
                            continue
                        other = self.roads[c.connecting_road]
                        sec = self._section_of(other, c.contact_point)
                        for a, b in c.lane_links:
                            if a == lid:
                                t = lane_or_warn(other.id, sec, b,
                                                 f"junction {rlink.element_id} connection {c.id}")
                                if t:
                                    targets.append(t)
            # The link against the driving direction (a forward lane's predecessor, a
            # backward lane's successor) builds nothing (CARLA links lanes from their
            # successors), but one naming a lane that does not exist is still a quirk
            # of the map: warn about it, as for the successor links.
            back_id = rec.predecessor if forward else rec.successor
            if back_id is not None:
                if (forward and k > 0) or (not forward and k < last):
                    lane_or_warn(rid, k - 1 if forward else k + 1, back_id,
                                 f"{where} {'predecessor' if forward else 'successor'}")
                else:
                    blink = road.predecessor if forward else road.successor
                    if (blink is not None and blink.element_type == "road"
                            and blink.element_id in self.roads):
                        other = self.roads[blink.element_id]
                        lane_or_warn(other.id, self._section_of(other, blink.contact_point),
                                     back_id,
                                     f"{where} {'predecessor' if forward else 'successor'}")
            seen = set()
            for t in targets:
                if t not in seen:
                    seen.add(t)
                    lane.successors.append(t)
                    self.lanes[t].predecessors.append(lane.key)

    # ------------------------------------------------------------------ lane geometry
    def _section_centres(self, road: RoadRecord, k: int, s: np.ndarray):
        """Centre offsets of every lane of a section at road s (OpenDRIVE frame).

        Returns {lane_id: (t, dt/ds, width)} with t the signed lateral offset of
        the lane centre from the reference line (left positive), metres.
        """
        sec = road.sections[k]
        ds = s - sec.s
        off, doff = road.lane_offset.value_and_derivative(s)
        out = {}
        for side in (-1, 1):
            inner, dinner = off, doff
            ids = sorted((i for i in sec.lanes if i * side > 0), key=abs)
            for lid in ids:
                rec = sec.lanes[lid]
                if rec.border is not None:
                    b, db = rec.border.value_and_derivative(ds)
                    outer = off + b * side
                    douter = doff + db * side
                    w = np.abs(outer - inner)
                    dw = (douter - dinner) * side
                else:
                    w, dw = rec.width.value_and_derivative(ds)
                    outer = inner + side * w
                    douter = dinner + side * dw
                out[lid] = (inner + 0.5 * side * w, dinner + 0.5 * side * dw, w)
                inner, dinner = outer, douter
        return out

    def _lane_frame(self, key: LaneKey, s: np.ndarray):
        """CARLA-frame centre x, y, z and tangent angle along +s (rad), and width."""
        road = self.roads[key[0]]
        xr, yr, hr, kr = road.plan_view.evaluate(s)
        t, dt, w = self._section_centres(road, key[1], s)[key[2]]
        x = xr - t * np.sin(hr)
        y = yr + t * np.cos(hr)
        h = hr + np.arctan2(dt, 1.0 - t * kr)
        z = road.elevation(s)
        return x, -y, z, -h, w

    def _lane_pose(self, key: LaneKey, s: np.ndarray):
        x, y, z, h, _ = self._lane_frame(key, s)
        yaw = np.degrees(h) + (180.0 if key[2] > 0 else 0.0)
        return x, y, z, normalize_yaw(yaw)

    def _lane_width(self, key: LaneKey, s: np.ndarray) -> np.ndarray:
        road = self.roads[key[0]]
        return self._section_centres(road, key[1], s)[key[2]][2]

    @staticmethod
    def _section_samples(road: RoadRecord, k: int, s0: float, s1: float,
                         step: float) -> np.ndarray:
        """Road s of a section's samples: ≤ `step` apart, and on every breakpoint.

        Samples sit exactly on plan-view joints, laneOffset records and width
        records, so no sample segment straddles a curvature or width discontinuity
        (the Hermite refinement assumes a smooth curve between its two samples).
        """
        sec = road.sections[k]
        lo, hi = s0 + 1e-6, s1 - 1e-6
        knots = {s0, s1}
        for x in road.plan_view.starts.tolist():
            if lo < x < hi:
                knots.add(x)
        for x in road.lane_offset.starts.tolist():
            if lo < x < hi:
                knots.add(x)
        for rec in sec.lanes.values():
            for cubic in (rec.width, rec.border):
                if cubic is not None and len(cubic.starts) > 1:
                    for x in cubic.starts.tolist():
                        if lo < sec.s + x < hi:
                            knots.add(sec.s + x)
        if len(knots) == 2:
            return _linspace(s0, s1, max(2, math.ceil((s1 - s0) / step) + 1))
        # Between consecutive knots a < c: _linspace(a, c, n) without its last point,
        # all intervals at once (the same products and sums, so the same bits).
        ordered = np.array(sorted(knots))
        a, c = ordered[:-1], ordered[1:]
        n = np.maximum(2, np.ceil((c - a) / step).astype(np.int64) + 1)
        m = n - 1
        first = np.cumsum(m) - m
        i = np.arange(int(m.sum())) - np.repeat(first, m)
        out = np.empty(len(i) + 1)
        np.add(i * np.repeat((c - a) / m, m), np.repeat(a, m), out=out[:-1])
        out[-1] = s1
        return out

    def _sample_lanes(self) -> None:
        xs, ys, zs, hs, ss, ws, owner, lane_n = [], [], [], [], [], [], [], []
        step = self.sample_step_m
        n_total = 0
        for road in self.roads.values():
            xr_all = None
            for k, sec in enumerate(road.sections):
                s0, s1 = sec.s, road.section_ends[k]
                if not sec.lanes:
                    continue
                s = self._section_samples(road, k, s0, s1, step)
                n = len(s)
                xr_all = road.plan_view.evaluate_sorted(s)
                xr, yr, hr, kr = xr_all
                sn, cs = np.sin(hr), np.cos(hr)
                z = road.elevation(s)
                centres = self._section_centres(road, k, s)
                lids = list(centres)
                t = np.array([centres[i][0] for i in lids])  # (L, n): all lanes at once
                dt = np.array([centres[i][1] for i in lids])
                for j, lid in enumerate(lids):
                    lane = self.lanes[(road.id, k, lid)]
                    lane.v0, lane.v1 = n_total + j * n, n_total + (j + 1) * n
                    owner.append(lane.index)
                    lane_n.append(n)
                n_total += len(lids) * n
                xs.append((xr - t * sn).ravel())
                ys.append((-(yr + t * cs)).ravel())
                hs.append((-(hr + np.arctan2(dt, 1.0 - t * kr))).ravel())
                zs += [z] * len(lids)  # the section's samples, once per lane
                ss += [s] * len(lids)
                ws.append(np.concatenate([centres[i][2] for i in lids]))
        self._vx = np.concatenate(xs)
        self._vy = np.concatenate(ys)
        self._vz = np.concatenate(zs)
        self._vh = np.concatenate(hs)
        self._vs = np.concatenate(ss)
        self._vw = np.concatenate(ws)
        self._vlane = np.repeat(np.array(owner, dtype=np.int32), lane_n)
        same = self._vlane[:-1] == self._vlane[1:]
        self._seg = np.flatnonzero(same & (self._vs[1:] > self._vs[:-1]))  # segment i: v[i]→v[i+1]
        self._lane_types = np.array([int(ln.type) for ln in self.lane_list], dtype=np.int64)
        self._lane_keys = np.array([ln.key for ln in self.lane_list], dtype=np.int64).reshape(-1, 3)

    # ------------------------------------------------------------------ spatial index
    def _index(self, lane_type: LaneType) -> tuple[cKDTree, np.ndarray, float]:
        """Plan-view index of the lane-centre segments of a type: k-d tree of the
        segment midpoints (x, y), the segment ids, and the largest half length."""
        key = int(lane_type)
        if key not in self._trees:
            seg = self._segments_of(lane_type)
            mx = 0.5 * (self._vx[seg] + self._vx[seg + 1])
            my = 0.5 * (self._vy[seg] + self._vy[seg + 1])
            half = 0.5 * np.hypot(self._vx[seg + 1] - self._vx[seg],
                                  self._vy[seg + 1] - self._vy[seg])
            self._trees[key] = (cKDTree(np.column_stack([mx, my])), seg, float(half.max()))
        return self._trees[key]

    def _index3(self, lane_type: LaneType) -> tuple[cKDTree, np.ndarray, float]:
        """As `_index`, in 3-D: midpoints (x, y, z) and the largest 3-D half length.

        Built on the first query that carries a z."""
        key = -int(lane_type)  # negative keys: the 3-D trees
        if key not in self._trees:
            seg = self._segments_of(lane_type)
            a = np.column_stack([self._vx[seg], self._vy[seg], self._vz[seg]])
            b = np.column_stack([self._vx[seg + 1], self._vy[seg + 1], self._vz[seg + 1]])
            half = 0.5 * np.sqrt(((b - a) ** 2).sum(axis=1))
            self._trees[key] = (cKDTree(0.5 * (a + b)), seg, float(half.max()))
        return self._trees[key]

    def _segments_of(self, lane_type: LaneType) -> np.ndarray:
        seg = self._seg[(self._lane_types[self._vlane[self._seg]] & int(lane_type)) != 0]
        if len(seg) == 0:
            raise OffRoadError(f"{self.name} has no lanes of type {lane_type!r}")
        return seg

    def _nearest_segments(self, q: np.ndarray, lane_type: LaneType) -> np.ndarray:
        """Id of the nearest lane-centre segment to each row of q, exactly.

        q is (N, 2) (plan-view distance) or (N, 3) (3-D distance, CARLA's rule).
        """
        three = q.shape[1] == 3
        tree, seg, half = self._index3(lane_type) if three else self._index(lane_type)
        if len(q) == 0:
            return np.zeros(0, dtype=np.int64)
        dist_fn = self._segment_distance3 if three else self._segment_distance
        n_seg = len(seg)
        k = min(8, n_seg)
        d, j = tree.query(q, k=k)
        d = d.reshape(len(q), -1)
        cand = seg[j.reshape(len(q), -1)]
        dist = dist_fn(q[:, None, :], cand)
        a = np.argmin(dist, axis=1)
        rows = np.arange(len(q))
        best = cand[rows, a]
        best_d = dist[rows, a]
        # A segment whose midpoint is farther than best_d + half cannot beat best_d;
        # where the k-th midpoint is nearer than that, look at every such segment.
        unsure = np.flatnonzero((d[:, -1] - half < best_d) & (k < n_seg))
        if len(unsure):
            lists = tree.query_ball_point(q[unsure], best_d[unsure] + half + 1e-9,
                                          return_sorted=False)
            counts = np.fromiter((len(c) for c in lists), dtype=np.int64, count=len(lists))
            flat = seg[np.fromiter((i for c in lists for i in c), dtype=np.int64,
                                   count=int(counts.sum()))]
            owner = np.repeat(unsure, counts)
            dd = dist_fn(q[owner], flat)
            starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
            order = np.lexsort((dd, owner))  # per point, nearest first
            first = order[starts]
            better = dd[first] < best_d[unsure]
            best[unsure[better]] = flat[first[better]]
            best_d[unsure[better]] = dd[first[better]]
        return best

    def project(self, points, lane_type: LaneType = LaneType.Driving) -> LaneProjection:
        """Project many points onto the nearest lane centre of the given type(s).

        Args:
            points: (N, 2) or (N, 3) array, CARLA world, metres. With a z column
                the lane is chosen by 3-D distance (the module's z rule, CARLA's);
                a row whose z is NaN is matched in plan view.
            lane_type: a `LaneType` flag; lanes of any type in the flag are searched.

        Returns:
            `LaneProjection` with one row per point.

        Raises:
            OffRoadError: the map has no lane of that type.
        """
        arr = np.asarray(points, dtype=float)
        arr = arr.reshape(-1, arr.shape[-1])
        pts = arr[:, :2]
        qz = arr[:, 2] if arr.shape[1] >= 3 else None
        has_z = np.isfinite(qz) if qz is not None else None
        if qz is None or not has_z.any():
            return self._refine(pts, self._nearest_segments(pts, lane_type))
        best = np.empty(len(pts), dtype=np.int64)
        rows3 = np.flatnonzero(has_z)
        best[rows3] = self._nearest_segments(np.column_stack([pts[rows3], qz[rows3]]),
                                             lane_type)
        rows2 = np.flatnonzero(~has_z)
        if len(rows2):
            best[rows2] = self._nearest_segments(pts[rows2], lane_type)
        return self._refine(pts, best, qz)

    def candidates(self, location, radius_m: float,
                   lane_type: LaneType = LaneType.Driving) -> LaneProjection:
        """Every lane whose centre line passes within `radius_m` of a point.

        One row per lane (its nearest foot point), sorted by distance; empty when
        no lane is that close. CARLA world, metres. When `location` carries a z
        (a `Location`, carla.Location or (x, y, z)), distances are 3-D (the
        module's z rule), so a road 10 m above or below is 10 m away, and
        `distance_m` is 3-D; with (x, y) they are plan-view, as before.

        Example:
            >>> c = m.candidates((10.0, 2.0), radius_m=8.0)  # doctest: +SKIP
            >>> list(zip(c.road_id, c.lane_id))  # doctest: +SKIP
        """
        x, y, z = as_xyz(location)
        if z is None:
            q = np.array([x, y])
            tree, seg, half = self._index(lane_type)
            dist_fn = self._segment_distance
        else:
            q = np.array([x, y, z])
            tree, seg, half = self._index3(lane_type)
            dist_fn = self._segment_distance3
        idx = np.asarray(tree.query_ball_point(q, radius_m + half), dtype=np.int64)
        segs = seg[idx]
        d = dist_fn(q[None, :], segs)
        keep = d <= radius_m
        segs, d = segs[keep], d[keep]
        order = np.lexsort((d, self._vlane[segs]))
        segs, d = segs[order], d[order]
        lanes = self._vlane[segs]
        first = np.concatenate([[True], lanes[1:] != lanes[:-1]]) if len(lanes) else lanes
        segs, d = segs[first], d[first]
        segs = segs[np.argsort(d, kind="stable")]
        n = len(segs)
        return self._refine(np.repeat(q[None, :2], n, axis=0), segs,
                            None if z is None else np.full(n, z))

    def _segment_distance(self, q: np.ndarray, i: np.ndarray) -> np.ndarray:
        ax, ay = self._vx[i], self._vy[i]
        bx, by = self._vx[i + 1], self._vy[i + 1]
        dx, dy = bx - ax, by - ay
        l2 = dx * dx + dy * dy
        t = ((q[..., 0] - ax) * dx + (q[..., 1] - ay) * dy) / np.where(l2 > 0, l2, 1.0)
        np.clip(t, 0.0, 1.0, out=t)
        return np.hypot(ax + t * dx - q[..., 0], ay + t * dy - q[..., 1])

    def _segment_distance3(self, q: np.ndarray, i: np.ndarray) -> np.ndarray:
        """3-D distance from points q (..., 3) to the 3-D segments i (CARLA's metric)."""
        ax, ay, az = self._vx[i], self._vy[i], self._vz[i]
        dx, dy, dz = self._vx[i + 1] - ax, self._vy[i + 1] - ay, self._vz[i + 1] - az
        l2 = dx * dx + dy * dy + dz * dz
        px, py, pz = q[..., 0] - ax, q[..., 1] - ay, q[..., 2] - az
        t = (px * dx + py * dy + pz * dz) / np.where(l2 > 0, l2, 1.0)
        np.clip(t, 0.0, 1.0, out=t)
        ex, ey, ez = t * dx - px, t * dy - py, t * dz - pz
        return np.sqrt(ex * ex + ey * ey + ez * ez)

    def _refine(self, q: np.ndarray, i: np.ndarray, qz: np.ndarray | None = None
                ) -> LaneProjection:
        """Foot point on the cubic Hermite curve of segment i (Newton, from the chord).

        The foot point is the plan-view one; `qz` (N,), NaN where unknown, only
        makes `distance_m` 3-D where it is given.
        """
        p0 = np.column_stack([self._vx[i], self._vy[i]])
        p1 = np.column_stack([self._vx[i + 1], self._vy[i + 1]])
        chord = np.linalg.norm(p1 - p0, axis=1)[:, None]
        t0 = np.column_stack([np.cos(self._vh[i]), np.sin(self._vh[i])]) * chord
        t1 = np.column_stack([np.cos(self._vh[i + 1]), np.sin(self._vh[i + 1])]) * chord
        d = p1 - p0
        t = np.clip(np.einsum("ij,ij->i", q - p0, d) / np.maximum(chord[:, 0] ** 2, 1e-18), 0, 1)
        for _ in range(3):
            c, c1, c2 = _hermite(p0, t0, p1, t1, t[:, None])
            r = c - q
            g = np.einsum("ij,ij->i", r, c1)
            dg = np.einsum("ij,ij->i", c1, c1) + np.einsum("ij,ij->i", r, c2)
            t = np.clip(t - g / np.where(np.abs(dg) > 1e-12, dg, 1e-12), 0.0, 1.0)
        c, c1, _ = _hermite(p0, t0, p1, t1, t[:, None])
        lane_idx = self._vlane[i]
        keys = self._lane_keys[lane_idx]
        s = self._vs[i] + t * (self._vs[i + 1] - self._vs[i])
        heading = np.arctan2(c1[:, 1], c1[:, 0])  # along +s, CARLA frame
        backward = keys[:, 2] > 0
        yaw = normalize_yaw(np.degrees(heading) + np.where(backward, 180.0, 0.0))
        r = q - c
        # Right of the +s direction in CARLA's left-handed frame is (-sin h, cos h).
        lateral = -r[:, 0] * np.sin(heading) + r[:, 1] * np.cos(heading)
        lateral = np.where(backward, -lateral, lateral)
        w = self._vw[i] + t * (self._vw[i + 1] - self._vw[i])
        z = self._vz[i] + t * (self._vz[i + 1] - self._vz[i])
        dist = np.hypot(r[:, 0], r[:, 1])
        if qz is not None:
            dz = qz - z
            dist = np.where(np.isfinite(dz), np.hypot(dist, dz), dist)
        return LaneProjection(keys[:, 0], keys[:, 1], keys[:, 2], s, c[:, 0], c[:, 1], z, yaw,
                              lateral, dist, w, lane_idx.astype(np.int64), self)

    # ------------------------------------------------------------------ CARLA queries
    def get_waypoint(self, location, project_to_road: bool = True,
                     lane_type: LaneType = LaneType.Driving) -> Waypoint | None:
        """The lane-centre waypoint nearest to `location`, as `carla.Map.get_waypoint`.

        Args:
            location: `Location`, carla.Location or (x, y[, z]); CARLA world, metres.
                A location with a z is matched by 3-D distance, as CARLA does (a
                `Location` always has one, 0 by default); (x, y) in plan view.
            project_to_road: when False, return a waypoint only if the point lies
                within half a lane width of the nearest centre line, else None.
            lane_type: `LaneType` flag of the lanes to consider.
        """
        x, y, z = as_xyz(location)
        i = self._nearest_segment_one([x, y] if z is None else [x, y, z], lane_type)
        s, lateral, width = self._refine_one(x, y, i)
        if not project_to_road and not abs(lateral) <= 0.5 * width + 1e-9:
            return None
        rid, k, lid = self.lane_list[int(self._vlane[i])].key
        return tuple.__new__(Waypoint, (rid, k, lid, s, self))

    def _nearest_segment_one(self, q: list[float], lane_type: LaneType) -> int:
        """`_nearest_segments` for one point (x, y[, z]), with less overhead; same answer.

        One k-d query for the 32 nearest midpoints settles ~99 % of points: when no
        unseen segment can be nearer and the nearest is unique, it is the answer of
        any exact search. Otherwise (a possible nearer segment, or an exact tie
        between overlapping lanes) `_nearest_segments`' own steps run, so ties
        break the same way in both.
        """
        three = len(q) == 3
        tree, seg, half = self._index3(lane_type) if three else self._index(lane_type)
        dist_fn = self._segment_distance3 if three else self._segment_distance
        n_seg = len(seg)
        qa = np.array(q)
        k = min(32, n_seg)
        d, j = tree.query(q, k=k)
        if k == 1:  # the k-d tree answers scalars for k = 1
            d, j = np.atleast_1d(d), np.atleast_1d(j)
        cand = seg[j]
        dist = dist_fn(qa, cand)
        a = int(dist.argmin())
        best_d = dist[a]
        if (k == n_seg or float(d[-1]) - half >= best_d) and \
                np.count_nonzero(dist == best_d) == 1:
            return int(cand[a])
        k = min(8, n_seg)  # _nearest_segments' steps, for one point (the k-d tree
        d, j = tree.query(q, k=k)  # orders equal midpoint distances by k)
        d, j = np.atleast_1d(d), np.atleast_1d(j)
        cand = seg[j]
        dist = dist_fn(qa, cand)
        a = int(dist.argmin())
        best, best_d = int(cand[a]), float(dist[a])
        if k < n_seg and float(d[k - 1]) - half < best_d:
            idx = tree.query_ball_point(q, best_d + half + 1e-9, return_sorted=False)
            flat = seg[np.asarray(idx, dtype=np.int64)]
            dd = dist_fn(qa, flat)
            f = int(dd.argmin())
            if float(dd[f]) < best_d:
                best = int(flat[f])
        return best

    def _refine_one(self, x: float, y: float, i: int) -> tuple[float, float, float]:
        """`_refine` for one point in plain floats: (s, lateral offset, lane width).

        The same Newton steps on the same Hermite curve as `_refine`, operation for
        operation, so the answers agree to the last bits of a double.
        """
        vx, vy, vh = self._vx, self._vy, self._vh
        ax, ay, bx, by = float(vx[i]), float(vy[i]), float(vx[i + 1]), float(vy[i + 1])
        h0, h1 = float(vh[i]), float(vh[i + 1])
        dx, dy = bx - ax, by - ay
        chord = math.sqrt(dx * dx + dy * dy)
        t0x, t0y = math.cos(h0) * chord, math.sin(h0) * chord
        t1x, t1y = math.cos(h1) * chord, math.sin(h1) * chord
        t = ((x - ax) * dx + (y - ay) * dy) / max(chord * chord, 1e-18)
        t = min(max(t, 0.0), 1.0)
        for _ in range(3):
            t2 = t * t
            t3 = t2 * t
            b0, b1, b2, b3 = 2 * t3 - 3 * t2 + 1, t3 - 2 * t2 + t, -2 * t3 + 3 * t2, t3 - t2
            d0, d1, d2, d3 = (6 * t2 - 6 * t, 3 * t2 - 4 * t + 1, -6 * t2 + 6 * t,
                              3 * t2 - 2 * t)
            e0, e1, e2, e3 = 12 * t - 6, 6 * t - 4, 6 - 12 * t, 6 * t - 2
            rx = ax * b0 + t0x * b1 + bx * b2 + t1x * b3 - x
            ry = ay * b0 + t0y * b1 + by * b2 + t1y * b3 - y
            c1x = ax * d0 + t0x * d1 + bx * d2 + t1x * d3
            c1y = ay * d0 + t0y * d1 + by * d2 + t1y * d3
            c2x = ax * e0 + t0x * e1 + bx * e2 + t1x * e3
            c2y = ay * e0 + t0y * e1 + by * e2 + t1y * e3
            g = rx * c1x + ry * c1y
            dg = (c1x * c1x + c1y * c1y) + (rx * c2x + ry * c2y)
            t = min(max(t - g / (dg if abs(dg) > 1e-12 else 1e-12), 0.0), 1.0)
        t2 = t * t
        t3 = t2 * t
        b0, b1, b2, b3 = 2 * t3 - 3 * t2 + 1, t3 - 2 * t2 + t, -2 * t3 + 3 * t2, t3 - t2
        d0, d1, d2, d3 = 6 * t2 - 6 * t, 3 * t2 - 4 * t + 1, -6 * t2 + 6 * t, 3 * t2 - 2 * t
        cx = ax * b0 + t0x * b1 + bx * b2 + t1x * b3
        cy = ay * b0 + t0y * b1 + by * b2 + t1y * b3
        c1x = ax * d0 + t0x * d1 + bx * d2 + t1x * d3
        c1y = ay * d0 + t0y * d1 + by * d2 + t1y * d3
        s0 = float(self._vs[i])
        s = s0 + t * (float(self._vs[i + 1]) - s0)
        heading = math.atan2(c1y, c1x)
        rx, ry = x - cx, y - cy
        lateral = -rx * math.sin(heading) + ry * math.cos(heading)
        if self._lane_keys[self._vlane[i], 2] > 0:
            lateral = -lateral
        w0 = float(self._vw[i])
        return s, lateral, w0 + t * (float(self._vw[i + 1]) - w0)

    def get_waypoints(self, points, project_to_road: bool = True,
                      lane_type: LaneType = LaneType.Driving) -> list[Waypoint | None]:
        """`get_waypoint` for (N, 2) or (N, 3) points at once (z: see `project`)."""
        p = self.project(points, lane_type)
        wps = p.waypoints()
        if project_to_road:
            return wps
        return [w if ok else None for w, ok in zip(wps, p.inside.tolist(), strict=True)]

    def waypoint(self, road_id: int, section_id: int, lane_id: int, s: float) -> Waypoint:
        """The waypoint at (road, section, lane, s); s is clamped into the section.

        Raises:
            KeyError: no such lane, with the valid lanes of that road in the message.
        """
        key = (int(road_id), int(section_id), int(lane_id))
        lane = self.lanes.get(key)
        if lane is None:
            valid = sorted(k for k in self.lanes if k[0] == key[0])
            raise KeyError(f"{self.name}: no lane {key}; lanes of road {key[0]}: {valid}")
        return Waypoint(*key, float(min(max(s, lane.s0), lane.s1)), self)

    def get_waypoint_xodr(self, road_id: int, lane_id: int, s: float) -> Waypoint | None:
        """As `carla.Map.get_waypoint_xodr`: the lane at road s, or None."""
        road = self.roads.get(int(road_id))
        if road is None or not (0.0 <= s <= road.length):
            return None
        k = self.section_at(road, s)
        if (road.id, k, lane_id) not in self.lanes:
            return None
        return Waypoint(road.id, k, int(lane_id), float(s), self)

    @staticmethod
    def section_at(road: RoadRecord, s: float) -> int:
        starts = [sec.s for sec in road.sections]
        return max(0, int(np.searchsorted(starts, s, side="right")) - 1)

    def lane_start(self, key: LaneKey) -> Waypoint:
        """The waypoint where lane `key` begins in its driving direction."""
        return Waypoint(*key, self.lanes[key].start_s, self)

    def get_topology(self) -> list[tuple[Waypoint, Waypoint]]:
        """(start of a Driving lane, start of one successor lane) pairs, as CARLA's."""
        out = []
        lanes, make, driving = self.lanes, tuple.__new__, LaneType.Driving
        for lane in self.lane_list:
            if lane.type != driving or not lane.successors:
                continue
            a = make(Waypoint, (*lane.key, lane.s0 if lane.key[2] < 0 else lane.s1, self))
            for t in lane.successors:
                b = lanes[t]
                out.append((a, make(Waypoint, (*t, b.s0 if t[2] < 0 else b.s1, self))))
        return out

    def generate_waypoints(self, distance: float) -> list[Waypoint]:
        """Per road, s = ε, ε + d, … < length − ε; one waypoint per Driving lane at s.

        s accumulates as CARLA's loop does (s += d, not s = ε + i·d); every road
        starts from the same ε, so one accumulated sequence serves all roads.
        """
        if not distance > 0:
            raise ValueError(f"distance must be positive, got {distance}")
        eps = float(_EPS)
        longest = max((r[1] for r in self._road_driving), default=0.0)
        n = int((longest - 2.0 * eps) / distance) + 3
        steps = np.full(max(n, 1), float(distance))
        steps[0] = eps
        acc = np.cumsum(steps)  # sequential, as s += d
        while acc[-1] < longest - eps:  # rounding left the bound short: go on adding d
            more = np.full(n + 1, float(distance))
            more[0] = acc[-1]
            acc = np.concatenate([acc, np.cumsum(more)[1:]])
        svals = acc.tolist()
        out: list[Waypoint] = []
        make = partial(tuple.__new__, Waypoint)
        for rid, length, starts, per_section in self._road_driving:
            count = bisect_left(svals, length - eps)  # s < length - ε
            if count == 0:
                continue
            if len(per_section) == 1:
                runs = [(0, 0, count)]
            else:  # runs of s in one lane section (section_at's rule)
                runs = []
                for i in range(count):
                    k = max(0, bisect_right(starts, svals[i]) - 1)
                    if runs and runs[-1][0] == k:
                        runs[-1][2] = i + 1
                    else:
                        runs.append([k, i, i + 1])
            for k, a, b in runs:
                ids = per_section[k]
                m = len(ids)
                if m == 0:
                    continue
                ss = svals[a:b]
                c = b - a
                if m == 1:
                    out += map(make, zip(repeat(rid, c), repeat(k, c), repeat(ids[0], c), ss,
                                         repeat(self, c), strict=True))
                else:
                    s_rep = chain.from_iterable(zip(*([ss] * m), strict=True))  # s, s, …
                    out += map(make, zip(repeat(rid, c * m), repeat(k, c * m), ids * c, s_rep,
                                         repeat(self, c * m), strict=True))
        return out

    def _walk(self, wp: Waypoint, distance: float, forward: bool) -> list[Waypoint]:
        if not distance > 0:
            raise ValueError(f"distance must be positive, got {distance}")
        key = wp[:3]
        lane = self.lanes[key]
        s = wp[3]
        d = float(distance)
        if (key[2] < 0) == forward:  # moving towards increasing s
            if d <= lane.s1 - s + 1e-9:  # the common case: still on this lane
                return [tuple.__new__(Waypoint, (*key, float(min(max(s + d, lane.s0), lane.s1)),
                                                 self))]
        elif d <= s - lane.s0 + 1e-9:
            return [tuple.__new__(Waypoint, (*key, float(min(max(s - d, lane.s0), lane.s1)),
                                             self))]
        out: list[Waypoint] = []
        stack = [(key, s, d, 0)]
        while stack:
            key, s, d, depth = stack.pop()
            lane = self.lanes[key]
            along = lane.forward == forward  # moving towards increasing s?
            left = (lane.s1 - s) if along else (s - lane.s0)
            if d <= left + 1e-9 or depth > 256:
                ns = s + d if along else s - d
                out.append(Waypoint(*key, float(min(max(ns, lane.s0), lane.s1)), self))
                continue
            nxt = lane.successors if forward else lane.predecessors
            for t in nxt:
                tl = self.lanes[t]
                start = tl.start_s if forward else tl.end_s
                stack.append((t, start, d - max(left, 0.0), depth + 1))
        out.sort(key=lambda w: (w.road_id, w.section_id, w.lane_id))
        return out

    def _side_lane(self, wp: Waypoint, left: bool) -> Waypoint | None:
        lid = wp.lane_id
        # Left of the driving direction is towards the reference line on both sides.
        inward = 1 if lid < 0 else -1
        nid = lid + inward if left else lid - inward
        if nid == 0:
            nid = inward
        key = (wp.road_id, wp.section_id, nid)
        if key not in self.lanes:
            return None
        return Waypoint(*key, wp.s, self)

    # ------------------------------------------------------------------ summaries
    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) of the road reference lines, CARLA frame, metres."""
        xs, ys = [], []
        for road in self.roads.values():
            s = np.linspace(0.0, road.length, max(2, int(road.length / 0.5) + 1))
            x, y, _, _ = road.plan_view.evaluate(s)
            xs.append(x)
            ys.append(-y)
        x, y = np.concatenate(xs), np.concatenate(ys)
        return float(x.min()), float(y.min()), float(x.max()), float(y.max())

    def driving_lanes(self) -> list[Lane]:
        return [ln for ln in self.lane_list if ln.type == LaneType.Driving]

    def lane_polyline(self, key: LaneKey, driving_order: bool = True) -> np.ndarray:
        """The sampled centre line of a lane, (M, 3) x, y, z, CARLA world, metres."""
        lane = self.lanes[key]
        sl = slice(lane.v0, lane.v1)
        pts = np.column_stack([self._vx[sl], self._vy[sl], self._vz[sl]])
        return pts[::-1] if (driving_order and not lane.forward) else pts

    def lane_samples(self, key: LaneKey) -> LaneSamples:
        """A lane's exact centre-line samples (≤ 1 m apart, on every breakpoint).

        Arrays in increasing road s (not driving order): `s` (m), `x`, `y`, `z`
        (CARLA world, m), `heading` (rad, CARLA frame, tangent along +s), `width`
        (m). Read-only views into the map's sample store.
        """
        lane = self.lanes[key]
        sl = slice(lane.v0, lane.v1)
        views = []
        for arr in (self._vs, self._vx, self._vy, self._vz, self._vh, self._vw):
            v = arr[sl]
            v.flags.writeable = False
            views.append(v)
        return LaneSamples(*views)

    def lane_centres(self, lane_type: LaneType = LaneType.Driving):
        """Yield (lane, (M, 3) centre polyline in driving order) for lanes of a type."""
        for lane in self.lane_list:
            if lane.type & lane_type:
                yield lane, self.lane_polyline(lane.key)

    def lane_border_polylines(self, key: LaneKey) -> tuple[np.ndarray, np.ndarray]:
        """Left and right borders (w.r.t. +s) of a lane, (M, 2) each, CARLA frame."""
        lane = self.lanes[key]
        sl = slice(lane.v0, lane.v1)
        x, y, h, w = self._vx[sl], self._vy[sl], self._vh[sl], self._vw[sl]
        rx, ry = -np.sin(h), np.cos(h)  # right of +s in CARLA's frame
        right = np.column_stack([x + 0.5 * w * rx, y + 0.5 * w * ry])
        left = np.column_stack([x - 0.5 * w * rx, y - 0.5 * w * ry])
        return left, right

    def summary(self) -> dict:
        """Counts and extent, as `dashtraj map info` prints them."""
        x0, y0, x1, y1 = self.extent
        return {
            "map": self.name,
            "roads": len(self.roads),
            "junctions": len(self.junctions),
            "lane_sections": sum(len(r.sections) for r in self.roads.values()),
            "driving_lanes": len(self.driving_lanes()),
            "topology_pairs": len(self.get_topology()),
            "extent": {"x_min": x0, "y_min": y0, "x_max": x1, "y_max": y1},
        }

    def lane_graph(self, lane_change_cost_m: float = 15.0, turn_cost_m_per_rad: float = 0.0):
        """The directed lane graph (cached per lane-change and turn cost); see `LaneGraph`."""
        from dashtraj.roads.lanegraph import LaneGraph

        key = (float(lane_change_cost_m), float(turn_cost_m_per_rad))
        if key not in self._graphs:
            self._graphs[key] = LaneGraph(self, lane_change_cost_m=key[0],
                                          turn_cost_m_per_rad=key[1])
        return self._graphs[key]

    def route(self, origin, destination, lane_change_cost_m: float = 15.0,
              turn_cost_m_per_rad: float = 0.0):
        """Shortest route between two locations; see `LaneGraph.route`."""
        return self.lane_graph(lane_change_cost_m, turn_cost_m_per_rad).route(origin, destination)

    def __repr__(self) -> str:
        return f"RoadMap({self.name!r}, roads={len(self.roads)}, lanes={len(self.lanes)})"
