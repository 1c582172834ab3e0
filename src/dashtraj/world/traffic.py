"""Traffic on the lane graph: lane following, IDM car following, junction reservations.

Every vehicle is a point on a lane centre: (lane, progress p in metres from the
lane's start in its driving direction, speed) plus a planned list of lanes ahead
(its route). Vehicles never change lanes; at a lane's end they continue into the
next planned lane. Positions come from each lane's sampled centre line (samples
<= 1 m apart, exact on the curve) by linear interpolation over arc length,
vectorised over all vehicles at once.

Car following is the Intelligent Driver Model (M. Treiber, A. Hennecke, D.
Helbing, "Congested traffic states in empirical observations and microscopic
simulations", Phys. Rev. E 62, 1805, 2000):

    a = a_max [1 - (v / v0)^delta - (s* / s)^2],
    s* = s0 + max(0, v T + v dv / (2 sqrt(a_max b))),

with s the bumper-to-bumper gap to the leader found along the planned path (the
same lane ahead or the next planned lanes, up to ``lookahead_m``) and dv the
closing speed.

Junctions. A *region* is one junction's connecting lanes, merged with other
junctions joined to it by a non-junction lane shorter than the longest vehicle
plus a margin (that short lane joins the region). Rules:

1. A vehicle may enter a region only while it holds a reservation for its
   *passage* (the region lanes its route takes); otherwise its path ends in a
   stop line at the region's entry (IDM sees a standing obstacle there).
2. A vehicle becomes a *candidate* when it is the first vehicle on its path
   before the entry and within ``queue_window_m`` of it; candidates are queued by
   the time they became one (ties: lower vehicle id).
3. Two passages conflict when they differ and share a lane or have lanes whose
   centre lines come closer than the widest vehicle + 0.5 m (precomputed per
   region). Identical passages do not conflict: vehicles on one follow each other
   by IDM. A candidate is granted when its passage conflicts with no holder's and
   with no earlier candidate's that is waiting for a conflict to clear (so later
   arrivals cannot starve it), and there is room beyond the region's exit: free
   road of its length + ``exit_margin_m``, plus that of every holder bound for the
   same exit lane, so a holder never has to stop inside the region.
4. A holder releases its reservation once its rear has left the region.

No collision in a region: holders' passages are pairwise conflict-free or
identical (then IDM spaces them), and nobody else is inside. No stop in a region:
nothing stands in a holder's way inside, and the room it needs beyond the exit
stays free, because only a region's holders can enter the lanes that leave it
(checked when the network is built: an exit lane has no predecessor outside the
region) and the vehicles already there only move forward. No deadlock: a holder
always leaves in finite time (free road, positive desired speed); a candidate
waits only on holders (who leave), on earlier candidates (finitely many, each
granted once its own holders leave), or on room beyond the exit, which frees as
soon as the vehicles ahead drive on. A circular wait needs a closed loop of
lanes completely filled with stopped vehicles (gridlock), which the paper's
densities (<= 25 vehicles in a town) never reach. The tests run 25 vehicles for
two minutes on Town10HD and check nobody stands still for 90 s; queues at its
larger merged junction regions can last about a minute (the reservation is
per passage, not per lane segment, so it is conservative).

Frames and units: CARLA world (metres, yaw degrees, positive turning +x toward
+y); speeds m/s; time s.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import networkx as nx
import numpy as np

from dashtraj.errors import DashtrajError, NoRouteError
from dashtraj.roads.types import LaneType

ROLES: tuple[str, ...] = ("target", "observer", "agent")

OBSERVER_PLACEMENTS: tuple[str, ...] = ("meet", "random")
"""How observers are placed: "meet" (around the target's path, see
`TrafficSim._place_observers`) or "random" (anywhere, like agents)."""

MEET_ROLES: tuple[str, ...] = ("oncoming", "following", "crossing", "parked")
"""Observer roles of "meet" placement, and the side of the target each one sees:
oncoming → its front, following → its back, crossing → its side, parked → its front
then its side (it stands at the roadside facing the oncoming target, see
`TrafficSim._meet_parked`)."""

PARKED_GAP_M = 0.2
"""Clearance between a parked car's body and the edge of the driving lane it stands
beside, metres: its centre is lane_width/2 + width/2 + PARKED_GAP_M right of the
lane centre."""

PARKED_FACING_MAX_M = 8.0
"""A "meet" parked observer faces the target from the opposite roadside only when it
stands this close to the target's lane centre, metres (see `TrafficSim._meet_parked`)."""

PARKED_JUNCTION_CLEARANCE_M = 15.0
"""A parked car stands on a non-junction lane, its box this far from both lane ends."""


class TrafficError(DashtrajError):
    """The traffic cannot be set up (map too small for the vehicles asked for, ...)."""


@dataclass(frozen=True, slots=True)
class IDMParams:
    """Intelligent Driver Model parameters (Treiber et al. 2000), SI units."""

    desired_speed_mps: float = 9.0
    time_headway_s: float = 1.5
    min_gap_m: float = 2.0
    max_accel_mps2: float = 1.5
    comfort_decel_mps2: float = 2.0
    delta: float = 4.0
    max_decel_mps2: float = 9.0


@dataclass(frozen=True, slots=True)
class TrafficConfig:
    """Settings of the traffic model; JSON round-trip via `asdict` / `from_dict`.

    Attributes:
        step_s: simulation step, seconds (20 Hz default).
        lookahead_m: how far along its path a vehicle looks for a leader, metres.
        queue_window_m: distance to a junction region's entry within which the
            first vehicle of a lane queues for it, metres.
        exit_margin_m: room beyond the exit, in addition to the vehicle's length.
        speed_spread: desired speeds are drawn uniformly in v0 * (1 +- spread).
        target_wobble_m: amplitude of the target's lateral wobble, metres.
        target_speed_variation: relative amplitude of the target's slow speed changes.
        target_detour_prob: probability that the target's route goes via a random
            intermediate lane instead of the shortest way.
        target_trip_m: (min, max) length of a random target route, metres.
        observer_placement: one of `OBSERVER_PLACEMENTS`; "meet" places observers
            where the target will pass (see `TrafficSim._place_observers`).
        crossing_max_wait_s: longest a "crossing" observer waits at its junction
            for the target, seconds (from the start).
        oncoming_max_wait_s: longest an "oncoming" observer stands where it starts
            waiting for the target, seconds (from the start).
        parked_fraction: share of the observers that are parked cars (standing
            still at the roadside for the whole run, dashcam on; see
            `TrafficSim._park`). With "random" placement the last
            round(parked_fraction * n_observers) observers are parked at random
            roadside spots; with "meet" placement the role cycle gets a "parked"
            role (oncoming, crossing, following, parked, ...) when it is > 0 and
            none when it is 0 (then the cycle is oncoming, crossing, following).
        idm: car-following parameters.
    """

    step_s: float = 0.05
    lookahead_m: float = 60.0
    queue_window_m: float = 25.0
    exit_margin_m: float = 3.0
    speed_spread: float = 0.15
    target_wobble_m: float = 0.3
    target_speed_variation: float = 0.1
    target_detour_prob: float = 0.3
    target_trip_m: tuple[float, float] = (400.0, 900.0)
    observer_placement: str = "meet"
    crossing_max_wait_s: float = 60.0
    oncoming_max_wait_s: float = 40.0
    parked_fraction: float = 0.25
    idm: IDMParams = field(default_factory=IDMParams)

    def __post_init__(self) -> None:
        if self.observer_placement not in OBSERVER_PLACEMENTS:
            raise TrafficError(f"unknown observer placement {self.observer_placement!r}; "
                               f"valid: {', '.join(OBSERVER_PLACEMENTS)}")
        if not 0.0 <= self.parked_fraction <= 1.0:
            raise TrafficError(f"parked_fraction must be in [0, 1], got {self.parked_fraction}")

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> TrafficConfig:
        """Read `to_dict` output; a dict without ``observer_placement`` was written
        before "meet" existed and means "random"; one without ``parked_fraction``
        was written before parked observers existed and means 0."""
        d = dict(d)
        d.setdefault("observer_placement", "random")
        d.setdefault("parked_fraction", 0.0)
        d["idm"] = IDMParams(**d.get("idm", {}))
        if "target_trip_m" in d:
            d["target_trip_m"] = tuple(d["target_trip_m"])
        return cls(**d)


@dataclass(frozen=True, slots=True)
class VehicleSpec:
    """A vehicle to simulate: id, role (one of `ROLES`) and box size (metres)."""

    vehicle_id: int
    role: str
    length_m: float
    width_m: float
    height_m: float


CAPACITY_SPACING_M = 20.0
"""Lane length per vehicle when placing vehicles at the start of a run (metres): a
network holds about (length of its lanes outside junctions) / 20 m vehicles."""


def vehicle_capacity(net: LaneNetwork) -> int:
    """About how many vehicles `TrafficSim` can place on ``net`` at the start of a run.

    One per `CAPACITY_SPACING_M` metres of the lanes longer than 12 m outside junction
    regions (vehicles are placed there, at least 12 m plus half a length apart).
    """
    free = (net.region == -1) & (net.length > 12.0)
    return int(float(net.length[free].sum()) // CAPACITY_SPACING_M)


class LaneNetwork:
    """The drivable lanes of a map (largest strongly connected set of Driving lanes,
    lane-following links only), their sampled centre lines, and junction regions.

    Lanes are numbered 0..n-1 (`keys[i]` is the CARLA lane key). Progress p along
    lane i runs from 0 at its start to `length[i]` at its end, driving direction.
    """

    def __init__(self, road_map, max_vehicle_length_m: float = 12.5,
                 max_vehicle_width_m: float = 2.6):
        self.map = road_map
        g = nx.DiGraph()
        for ln in road_map.driving_lanes():
            g.add_node(ln.key)
            for s in ln.successors:
                if road_map.lanes[s].type == LaneType.Driving:
                    g.add_edge(ln.key, s)
        if g.number_of_nodes() == 0:
            raise TrafficError(f"{road_map.name}: the map has no driving lanes")
        scc = max(nx.strongly_connected_components(g), key=lambda c: (len(c), min(c)))
        self.keys: list[tuple[int, int, int]] = sorted(scc)
        self.index = {k: i for i, k in enumerate(self.keys)}
        n = len(self.keys)
        self.successors: list[list[int]] = [
            sorted(self.index[s] for s in g.successors(k) if s in self.index) for k in self.keys
        ]
        self.predecessors: list[list[int]] = [[] for _ in range(n)]
        for i, ss in enumerate(self.successors):
            for j in ss:
                self.predecessors[j].append(i)
        # sampled centre lines in driving order, concatenated; G is a global
        # monotone arc coordinate: lane i spans [base[i], base[i] + length[i]].
        xs, ys, zs, cs, sn, ss_, gs, ws = [], [], [], [], [], [], [], []
        self.length = np.zeros(n)
        self.base = np.zeros(n)
        offset = 0.0
        for i, key in enumerate(self.keys):
            lane = road_map.lanes[key]
            sl = slice(lane.v0, lane.v1)
            x, y, z = road_map._vx[sl], road_map._vy[sl], road_map._vz[sl]
            h, s, w = road_map._vh[sl], road_map._vs[sl], road_map._vw[sl]
            if not lane.forward:
                x, y, z, h, s, w = x[::-1], y[::-1], z[::-1], h[::-1] + math.pi, s[::-1], w[::-1]
            arc = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))])
            keep = np.concatenate([[True], np.diff(arc) > 1e-9])
            x, y, z, h, s, w, arc = (a[keep] for a in (x, y, z, h, s, w, arc))
            self.length[i] = arc[-1]
            self.base[i] = offset
            xs.append(x), ys.append(y), zs.append(z), cs.append(np.cos(h)), sn.append(np.sin(h))
            ss_.append(s), ws.append(w), gs.append(offset + arc)
            offset += arc[-1] + 10.0
        self._g = np.concatenate(gs)
        self._x, self._y, self._z = np.concatenate(xs), np.concatenate(ys), np.concatenate(zs)
        self._c, self._s = np.concatenate(cs), np.concatenate(sn)
        self._rs, self._w = np.concatenate(ss_), np.concatenate(ws)
        self._road = np.array([k[0] for k in self.keys], dtype=np.int64)
        self._section = np.array([k[1] for k in self.keys], dtype=np.int64)
        self._lane_id = np.array([k[2] for k in self.keys], dtype=np.int64)
        self._build_regions(max_vehicle_length_m)
        self._build_conflicts(max_vehicle_width_m + 0.5)
        self.graph = nx.DiGraph()
        for i in range(n):
            for j in self.successors[i]:
                self.graph.add_edge(i, j, weight=float(self.length[i]))

    def _build_regions(self, max_len: float) -> None:
        """Group junction lanes into regions (see the module docstring)."""
        m = self.map
        n = len(self.keys)
        junction = np.array([m.roads[k[0]].junction for k in self.keys])
        is_j = junction != -1
        short = max(15.0, max_len + 3.0)
        parent = {int(j): int(j) for j in set(junction[is_j].tolist())}

        def find(a):
            while parent[a] != a:
                parent[a] = parent[parent[a]]
                a = parent[a]
            return a

        extra: dict[int, int] = {}
        for i in range(n):
            if is_j[i] or self.length[i] >= short:
                continue
            pj = {int(junction[p]) for p in self.predecessors[i] if is_j[p]}
            sj = {int(junction[s]) for s in self.successors[i] if is_j[s]}
            if pj and sj:
                a = find(next(iter(pj)))
                for b in pj | sj:
                    parent[find(b)] = a
                extra[i] = next(iter(pj))
        roots = sorted({find(j) for j in parent})
        rid = {r: k for k, r in enumerate(roots)}
        self.region = np.full(n, -1, dtype=np.int64)
        for i in range(n):
            if is_j[i]:
                self.region[i] = rid[find(int(junction[i]))]
            elif i in extra:
                self.region[i] = rid[find(extra[i])]
        self.n_regions = len(roots)
        for i in range(n):  # the exit lanes of a region must be entered only from it
            if self.region[i] == -1:
                preds = {int(self.region[p]) for p in self.predecessors[i]}
                if len(preds) > 1 and any(r != -1 for r in preds):
                    raise TrafficError(
                        f"{m.name}: lane {self.keys[i]} is entered both from a junction and "
                        "from an ordinary lane; junction reservations cannot protect it")

    def _build_conflicts(self, clearance_m: float) -> None:
        """Pairs of region lanes whose centre lines come closer than `clearance_m`."""
        from scipy.spatial import cKDTree

        self.conflicts: set[tuple[int, int]] = set()
        lanes = np.searchsorted(self.base, self._g, side="right") - 1
        for r in range(self.n_regions):
            members = np.flatnonzero(self.region == r)
            sel = np.flatnonzero(np.isin(lanes, members))
            tree = cKDTree(np.column_stack([self._x[sel], self._y[sel]]))
            for a, b in tree.query_pairs(clearance_m):
                la, lb = int(lanes[sel[a]]), int(lanes[sel[b]])
                if la != lb:
                    self.conflicts.add((la, lb))
                    self.conflicts.add((lb, la))

    def paths_conflict(self, a: tuple[int, ...], b: tuple[int, ...]) -> bool:
        """Do two passages through a region (tuples of its lanes) conflict?

        The same passage does not (vehicles on it follow each other by IDM); two
        different ones do when they share a lane or any of their lanes come closer
        than the clearance.
        """
        if a == b:
            return False
        if set(a) & set(b):
            return True
        return any((x, y) in self.conflicts for x in a for y in b)

    # ------------------------------------------------------------------ geometry
    def pose(self, lane: np.ndarray, p: np.ndarray, lateral_m: np.ndarray | None = None):
        """Pose on lane centres, vectorised.

        Args:
            lane: (N,) int lane indices; p: (N,) progress, metres (clipped to the lane).
            lateral_m: (N,) offset to the right of the driving direction, metres, or None.

        Returns:
            x, y, z (metres, CARLA world), yaw (degrees, driving direction), road s (metres).
        """
        q = self.base[lane] + np.clip(p, 0.0, self.length[lane])
        x = np.interp(q, self._g, self._x)
        y = np.interp(q, self._g, self._y)
        z = np.interp(q, self._g, self._z)
        c = np.interp(q, self._g, self._c)
        s = np.interp(q, self._g, self._s)
        h = np.arctan2(s, c)
        if lateral_m is not None:
            x = x - lateral_m * np.sin(h)
            y = y + lateral_m * np.cos(h)
        return x, y, z, np.degrees(h), np.interp(q, self._g, self._rs)

    def width(self, lane: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Lane widths at progress p (metres), vectorised like `pose`."""
        q = self.base[lane] + np.clip(p, 0.0, self.length[lane])
        return np.interp(q, self._g, self._w)

    def lane_keys(self, lane: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(road_id, section_id, lane_id) arrays of lane indices."""
        return self._road[lane], self._section[lane], self._lane_id[lane]

    # ------------------------------------------------------------------ routing
    def shortest_lanes(self, a: int, b: int) -> list[int]:
        """Lane indices from a to b inclusive along lane links (a != b), shortest first."""
        try:
            return nx.shortest_path(self.graph, a, b, weight="weight")
        except nx.NetworkXNoPath as exc:  # pragma: no cover - the network is strongly connected
            raise NoRouteError(f"no route from lane {self.keys[a]} to {self.keys[b]}") from exc


def _wrap_deg(a):
    return (np.asarray(a) + 180.0) % 360.0 - 180.0


class TrafficSim:
    """The traffic simulation; call `step()` and read `frame()`.

    Args:
        network: the lanes.
        vehicles: one `VehicleSpec` per vehicle; at most one has role "target".
        config: model settings.
        rng: random generator (spawn places, speeds, routes, the target's style).
        target_route: optional ((x, y) origin, (x, y) destination), CARLA world metres;
            random when None.

    Attributes after each step: `t` (s), `target_arrived_t` (s or None).
    """

    def __init__(self, network: LaneNetwork, vehicles: list[VehicleSpec],
                 config: TrafficConfig, rng: np.random.Generator, target_route=None):
        self.net = network
        self.cfg = config
        self.rng = rng
        self.vehicles = list(vehicles)
        n = len(self.vehicles)
        self.n = n
        self.ids = np.array([v.vehicle_id for v in vehicles], dtype=np.int64)
        self.length = np.array([v.length_m for v in vehicles])
        self.width = np.array([v.width_m for v in vehicles])
        self.height = np.array([v.height_m for v in vehicles])
        roles = [v.role for v in vehicles]
        targets = [i for i, r in enumerate(roles) if r == "target"]
        if len(targets) > 1:
            raise TrafficError("at most one vehicle may have role 'target'")
        self.target = targets[0] if targets else None
        idm = config.idm
        self.v0 = idm.desired_speed_mps * rng.uniform(1 - config.speed_spread,
                                                      1 + config.speed_spread, n)
        self.t = 0.0
        self.target_arrived_t: float | None = None
        self.lane = np.zeros(n, dtype=np.int64)
        self.p = np.zeros(n)
        self.v = np.zeros(n)
        self.routes: list[list[int]] = [[] for _ in range(n)]
        self.headway = np.full(n, idm.time_headway_s)  # IDM time headway T per vehicle, s
        # observers waiting for the target ("meet"): vehicle -> (release when the target
        # has driven this far along its path (m), latest release time (s), stand still
        # where it is (True) or wait at the next junction's stop line (False))
        self.hold: dict[int, tuple[float, float, bool]] = {}
        self.meet_roles: dict[int, str] = {}  # observer index -> role in MEET_ROLES
        # parked observers: standing still beside their lane, park_lat m right of its centre
        self.parked = np.zeros(n, dtype=bool)
        self.park_lat = np.zeros(n)
        self._parked_xy: list[tuple[float, float, float]] = []  # x, y, radius
        self._target_hops = 0  # lanes the target has left behind (index in target_lanes)
        self._spawn()
        # junction regions
        # per region: {holder vehicle: (passage lanes, exit lane, entered)}
        self.holds: list[dict[int, tuple]] = [{} for _ in range(network.n_regions)]
        self.queue_since: dict[tuple[int, int], float] = {}  # (region, vehicle) -> t
        # target style
        self.dest: tuple[int, float] | None = None
        if self.target is not None:
            self._plan_target(target_route)
            k = self.target
            self._wob = (rng.uniform(6.0, 12.0), rng.uniform(3.0, 5.0),
                         rng.uniform(0, 2 * np.pi), rng.uniform(0, 2 * np.pi))
            self._spd = (rng.uniform(15.0, 30.0), rng.uniform(0, 2 * np.pi), self.v0[k])
            if config.observer_placement == "meet":
                self._place_observers()
        if config.observer_placement == "random" or self.target is None:
            self._park_share()

    # ------------------------------------------------------------------ set-up
    def _spawn(self) -> None:
        net, rng = self.net, self.rng
        free = np.flatnonzero((net.region == -1) & (net.length > 12.0))
        if len(free) == 0:
            raise TrafficError(f"{net.map.name}: no lane long enough to place a vehicle on")
        placed: dict[int, list[float]] = {}
        for i in range(self.n):
            for _attempt in range(500):
                lane = int(rng.choice(free, p=net.length[free] / net.length[free].sum()))
                half = 0.5 * self.length[i]
                lo, hi = half + 1.0, net.length[lane] - half - 4.0
                if hi <= lo:
                    continue
                p = float(rng.uniform(lo, hi))
                if all(abs(p - q) > 12.0 + half for q in placed.get(lane, [])):
                    break
            else:
                raise TrafficError(
                    f"{net.map.name}: no room to place {self.n} vehicles (it holds about "
                    f"{vehicle_capacity(net)}); ask for fewer")
            placed.setdefault(lane, []).append(p)
            self.lane[i], self.p[i] = lane, p

    def _plan_target(self, target_route) -> None:
        net, rng, k = self.net, self.rng, self.target
        if target_route is not None:
            (ox, oy), (dx, dy) = target_route
            lane, p = _nearest_lane(net, ox, oy, free_only=True)
            self.lane[k], self.p[k] = lane, p
            dest = _nearest_lane(net, dx, dy, free_only=True)
        else:
            dist = nx.single_source_dijkstra_path_length(net.graph, int(self.lane[k]))
            lo, hi = self.cfg.target_trip_m
            ok = [j for j, d in sorted(dist.items())
                  if net.region[j] == -1 and lo <= d - self.p[k] <= hi and j != self.lane[k]]
            if not ok:  # a small town: one of the farthest lanes
                far = 0.6 * max(dist.values())
                ok = [j for j in sorted(dist) if net.region[j] == -1 and j != self.lane[k]
                      and dist[j] >= far]
            j = int(rng.choice(ok))
            dest = (j, float(rng.uniform(0.3, 0.7) * net.length[j]))
        lanes = [int(self.lane[k])]
        if rng.random() < self.cfg.target_detour_prob:
            cand = [j for j in range(len(net.keys))
                    if net.region[j] == -1 and j not in (lanes[0], dest[0])]
            via = int(rng.choice(cand))
            lanes = net.shortest_lanes(lanes[0], via)
            lanes += net.shortest_lanes(via, dest[0])[1:]
        else:
            lanes = net.shortest_lanes(lanes[0], dest[0])
        self.routes[k] = lanes[1:]
        self.dest = dest
        self.target_lanes = lanes

    # ------------------------------------------------------------------ parked observers
    def _curb_lane(self, lane: int) -> int | None:
        """The outermost (rightmost in its driving direction) driving lane of lane's road
        section with the same direction, if it is in the network and not in a junction
        region; else None."""
        net = self.net
        road, sec, lid = net.keys[lane]
        same = [j for j in self._section_lanes(road, sec) if net.keys[j][2] * lid > 0]
        if not same:
            return None
        j = max(same, key=lambda q: (abs(net.keys[q][2]), q))
        return j if net.region[j] == -1 else None

    def _free_run(self, lane: int, ahead: bool, need: float) -> float:
        """Metres of non-junction lanes before `lane`'s start (ahead=False) or after its
        end (ahead=True) along every chain of lane links, up to `need`: 0 when a
        junction region lane adjoins it."""
        net = self.net
        nxt = net.successors[lane] if ahead else net.predecessors[lane]
        if need <= 0.0 or not nxt:
            return 0.0
        if any(net.region[q] != -1 for q in nxt):
            return 0.0
        return min(min(float(net.length[q]) + self._free_run(q, ahead, need - net.length[q]),
                       need) for q in nxt)

    def _park(self, i: int, lane: int, p: float, near=None) -> bool:
        """Park vehicle i beside `lane` at progress p, if the spot is a roadside one.

        The spot: a non-junction lane whose right neighbour (in its driving direction)
        is not a Driving lane; the box inside the lane and at least
        `PARKED_JUNCTION_CLEARANCE_M` from any junction region along the lane links
        (both ways); centre lane_width/2 + width/2 + `PARKED_GAP_M` right of the lane
        centre, yaw the lane's; every corner and edge midpoint of the box outside
        every driving lane of the map (more than 0.1 m beyond its half width); clear of
        the other parked cars; with ``near`` = (x, y, d), within d metres of (x, y).
        On success vehicle i stands there for the whole run.
        """
        net, m = self.net, self.net.map
        half = 0.5 * self.length[i]
        clear = PARKED_JUNCTION_CLEARANCE_M
        if net.region[lane] != -1 or not half <= p <= net.length[lane] - half:
            return False
        if p - half < clear and self._free_run(lane, False, clear) + p - half < clear:
            return False
        rest = net.length[lane] - p - half
        if rest < clear and self._free_run(lane, True, clear) + rest < clear:
            return False
        road, sec, lid = net.keys[lane]
        right = m.lanes.get((road, sec, lid + (1 if lid > 0 else -1)))
        if right is not None and right.type == LaneType.Driving:
            return False
        lane_a, p_a = np.array([lane]), np.array([p])
        lat = 0.5 * float(net.width(lane_a, p_a)[0]) + 0.5 * self.width[i] + PARKED_GAP_M
        x, y, _z, yaw, _s = net.pose(lane_a, p_a, np.array([lat]))
        if near is not None and math.hypot(x[0] - near[0], y[0] - near[1]) > near[2]:
            return False
        h = math.radians(float(yaw[0]))
        c, sn = math.cos(h), math.sin(h)
        hw = 0.5 * self.width[i]
        pts = np.array([(x[0] + a * half * c - b * hw * sn, y[0] + a * half * sn + b * hw * c)
                        for a in (-1, 0, 1) for b in (-1, 0, 1) if a or b])
        proj = m.project(pts, LaneType.Driving)
        if np.any(np.abs(proj.lateral_m) <= 0.5 * proj.lane_width + 0.1):
            return False
        r = math.hypot(half, hw)
        if any(math.hypot(x[0] - px, y[0] - py) <= r + pr + 0.5
               for px, py, pr in self._parked_xy):
            return False
        self.lane[i], self.p[i], self.v[i] = lane, p, 0.0
        self.routes[i] = []
        self.parked[i] = True
        self.park_lat[i] = lat
        self._parked_xy.append((float(x[0]), float(y[0]), r))
        return True

    def _park_share(self) -> None:
        """Park the last round(`parked_fraction` * n_observers) observers at random
        roadside spots ("random" placement)."""
        net, rng = self.net, self.rng
        obs = [i for i, v in enumerate(self.vehicles) if v.role == "observer"]
        k = math.floor(self.cfg.parked_fraction * len(obs) + 0.5)
        if k == 0:
            return
        free = np.flatnonzero((net.region == -1) & (net.length > 12.0))
        if len(free) == 0:
            raise TrafficError(f"{net.map.name}: no lane long enough to park a car beside")
        for i in obs[-k:]:
            for _attempt in range(500):
                lane = int(rng.choice(free, p=net.length[free] / net.length[free].sum()))
                if self._park(i, lane, float(rng.uniform(0.0, net.length[lane]))):
                    break
            else:
                raise TrafficError(f"{net.map.name}: found no roadside spot to park observer "
                                   f"{int(self.ids[i])}; ask for a smaller parked fraction")

    def _meet_parked(self, i, d, start, placed, reserved) -> bool:
        """Park beside the target's path near distance d along it (path lanes tried in
        order of distance from d, spots shifted by up to 18 m).

        Per path lane, first facing the target: at the roadside of the opposite
        direction's outermost lane, if that spot is within `PARKED_FACING_MAX_M` of
        the target's lane centre (a two-lane road, e.g. Town01: about 7 m), at least
        40 m ahead of the target's start; it sees the target's front as it
        approaches, then its side as it passes. Else at the roadside of the target's
        own direction (its outermost lane), at least 30 m ahead: the target passes
        lane_width/2 + width/2 + `PARKED_GAP_M` (about 3 m) away when it drives in
        that lane, and the dashcam, facing the same way, sees its side as it passes,
        then its back. (A car parked on the right, facing its lane's direction, cannot
        see the front of a car coming from behind; on multi-lane roads such as
        Town10's the opposite roadside is 10 m or more away, too far to see much.)"""
        net, path = self.net, self.target_lanes
        ends = start + net.length[path]
        order = sorted(range(len(path)), key=lambda j: (abs(min(max(d, start[j]), ends[j]) - d), j))
        for j in order:
            lane = path[j]
            if net.region[lane] != -1:
                continue
            q = min(max(d - start[j], 0.0), net.length[lane])
            o = self._opposite(lane)
            o = self._curb_lane(o) if o is not None else None
            if o is not None:
                po = (1.0 - q / net.length[lane]) * net.length[o]
                for shift in (0.0, 6.0, -6.0, 12.0, -12.0, 18.0, -18.0):
                    ahead = start[j] + (1.0 - (po + shift) / net.length[o]) * net.length[lane]
                    if ahead < 40.0:
                        continue
                    q_t = np.array([(1.0 - (po + shift) / net.length[o]) * net.length[lane]])
                    tx, ty, *_ = net.pose(np.array([lane]), q_t)
                    if self._park(i, o, po + shift,
                                  near=(tx[0], ty[0], PARKED_FACING_MAX_M)):
                        return True
            c = self._curb_lane(lane)
            if c is not None:
                pc = q / net.length[lane] * net.length[c]
                for shift in (0.0, 6.0, -6.0, 12.0, -12.0, 18.0, -18.0):
                    ahead = start[j] + (pc + shift) / net.length[c] * net.length[lane]
                    if ahead >= 30.0 and self._park(i, c, pc + shift):
                        return True
        return False

    # ------------------------------------------------------------------ meet placement
    def _place_observers(self) -> None:
        """Place the observers where the target will pass ("meet" placement).

        The target's planned path (`target_lanes`, distance measured from the
        target's start) is split evenly: observer m gets the point at fraction
        (m + u) / n_observers of its length, u ~ U(0.25, 0.75), and the role
        oncoming, crossing, following, parked, oncoming, ... (m = 0, 1, 2, ...;
        without "parked" when `TrafficConfig.parked_fraction` is 0):

        - oncoming: on the opposite-direction lane (same road and section, the
          driving lane nearest the centre) at that point, at least 30 m ahead of
          the target; its route is the target's path reversed on opposite lanes
          (consecutive ones joined by `LaneNetwork.shortest_lanes`, one-way roads
          skipped), so the two pass each other a lane apart: it sees the front.
          It stands still until the target is 50 m away (at most
          `oncoming_max_wait_s`), so that they meet near that point, not in a
          junction on the way.
        - following (at most one): 20-50 m behind the target on the lanes leading
          into its first lane, on the target's path, 40 % faster with a 0.8 s
          headway: it sees the back.
        - crossing: on a side road entering the junction region of the target's
          path nearest that point (heading as close to perpendicular as found),
          10-25 m before the entry, with a route across the region; it drives up
          to the stop line and waits there (without queueing) until the target has
          left the region or `crossing_max_wait_s` passed: it sees the side.
        - parked: stands still at the roadside beside the target's path for the
          whole run (`_meet_parked`, `_park`): it sees the front, then the side.
          It is not in a driving lane and does not take part in car following.

        A role that finds no room falls back to the others, then to a random
        place. Agents left overlapping an observer (same lane, closer than the
        `_spawn` spacing) or standing between a crossing observer and its stop
        line are placed again at random.
        """
        net, rng, k = self.net, self.rng, self.target
        obs = [i for i, v in enumerate(self.vehicles) if v.role == "observer"]
        if not obs:
            return
        path = self.target_lanes
        start = np.concatenate([[0.0], np.cumsum(net.length[path])])[:-1] - self.p[k]
        self._path_start = start
        total = max(float(start[-1] + self.dest[1]), 1.0)
        placed: dict[int, list[tuple[float, float]]] = {}
        reserved: dict[int, list[tuple[float, float]]] = {}
        placed.setdefault(int(self.lane[k]), []).append((float(self.p[k]), 0.5 * self.length[k]))
        n = len(obs)
        used_following = False
        cycle = ("oncoming", "crossing", "following", "parked")
        if self.cfg.parked_fraction <= 0.0:
            cycle = cycle[:3]
        for m, i in enumerate(obs):
            role = cycle[m % len(cycle)]
            d = (m + rng.uniform(0.25, 0.75)) / n * total
            done = None
            for r in [role, *[x for x in MEET_ROLES if x != role]]:
                if r == "following" and used_following:
                    continue
                if r == "parked" and "parked" not in cycle:
                    continue
                if getattr(self, f"_meet_{r}")(i, d, start, placed, reserved):
                    done = r
                    break
            if done is None:
                self._place_random(i, placed, reserved)
                continue
            used_following |= done == "following"
            self.meet_roles[i] = done
            if done == "parked":  # beside the lane, not in it: takes no room on it
                continue
            placed.setdefault(int(self.lane[i]), []).append((float(self.p[i]),
                                                             0.5 * self.length[i]))
        for i, v in enumerate(self.vehicles):
            if v.role == "agent":
                if not self._spot_free(int(self.lane[i]), float(self.p[i]),
                                       0.5 * self.length[i], placed, reserved):
                    self._place_random(i, placed, reserved)
                placed.setdefault(int(self.lane[i]), []).append(
                    (float(self.p[i]), 0.5 * self.length[i]))

    def _spot_free(self, lane: int, p: float, half: float, placed, reserved) -> bool:
        """Is (lane, p) inside a non-junction lane and `_spawn`'s spacing away from
        every placed vehicle and outside the reserved stretches?"""
        net = self.net
        if net.region[lane] != -1 or not half + 1.0 <= p <= net.length[lane] - half - 4.0:
            return False
        if any(abs(p - q) <= 12.0 + max(half, h) for q, h in placed.get(lane, ())):
            return False
        return not any(a - half - 12.0 <= p <= b for a, b in reserved.get(lane, ()))

    def _place_random(self, i: int, placed, reserved) -> None:
        net, rng = self.net, self.rng
        free = np.flatnonzero((net.region == -1) & (net.length > 12.0))
        half = 0.5 * self.length[i]
        for _attempt in range(500):
            lane = int(rng.choice(free, p=net.length[free] / net.length[free].sum()))
            lo, hi = half + 1.0, net.length[lane] - half - 4.0
            if hi <= lo:
                continue
            p = float(rng.uniform(lo, hi))
            if self._spot_free(lane, p, half, placed, reserved):
                self.lane[i], self.p[i] = lane, p
                self.routes[i] = []
                return
        raise TrafficError(f"{net.map.name}: no room to place {self.n} vehicles (it holds "
                          f"about {vehicle_capacity(net)}); ask for fewer")

    def _opposite(self, lane: int) -> int | None:
        """The opposite-direction driving lane of the same road section nearest the
        centre, or None (one-way road, or that lane is not in the network)."""
        net = self.net
        road, sec, lid = net.keys[lane]
        opp = [j for j in self._section_lanes(road, sec) if net.keys[j][2] * lid < 0]
        return min(opp, key=lambda j: (abs(net.keys[j][2]), j)) if opp else None

    def _meet_oncoming(self, i, d, start, placed, reserved) -> bool:
        net, path = self.net, self.target_lanes
        half = 0.5 * self.length[i]
        d = max(d, 40.0)
        ends = start + net.length[path]
        order = sorted(range(len(path)), key=lambda j: (abs(min(max(d, start[j]), ends[j]) - d), j))
        for j in order:
            lane = path[j]
            o = self._opposite(lane) if net.region[lane] == -1 else None
            if o is None:
                continue
            q = min(max(d - start[j], 0.0), net.length[lane])
            po = (1.0 - q / net.length[lane]) * net.length[o]
            for shift in (0.0, 8.0, -8.0, 16.0, -16.0, 24.0, -24.0):
                p = po + shift
                ahead = start[j] + (1.0 - p / net.length[o]) * net.length[lane]
                if ahead >= 30.0 and self._spot_free(o, p, half, placed, reserved):
                    self.lane[i], self.p[i] = o, p
                    self.routes[i] = self._reverse_route(o, j)
                    if ahead > 60.0:  # wait until the target is 50 m away, then drive
                        self.hold[i] = (float(ahead) - 50.0, self.cfg.oncoming_max_wait_s, True)
                    return True
        return False

    def _reverse_route(self, o: int, j: int) -> list[int]:
        """Route from lane o (opposite to target_lanes[j]) back along the target's path
        on opposite-direction lanes: for each earlier non-junction lane of the path,
        the opposite lane reachable by the shortest way no longer than that stretch
        of the path + 60 m (lanes without one, one-way roads, are skipped)."""
        net, path = self.net, self.target_lanes
        route, last_j = [o], j
        for jj in range(j - 1, -1, -1):
            lane = path[jj]
            if net.region[lane] != -1:
                continue
            road, sec, lid = net.keys[lane]
            opp = [q for q in self._section_lanes(road, sec) if net.keys[q][2] * lid < 0]
            if not opp or route[-1] in opp:
                if route[-1] in opp:
                    last_j = jj
                continue
            cutoff = float(net.length[path[jj:last_j + 1]].sum()) + 60.0
            dist = nx.single_source_dijkstra_path_length(net.graph, route[-1], cutoff=cutoff)
            reach = [(dist[q], q) for q in opp if q in dist]
            if not reach:
                continue
            route += net.shortest_lanes(route[-1], min(reach)[1])[1:]
            last_j = jj
        return route[1:]

    def _section_lanes(self, road: int, sec: int) -> list[int]:
        if not hasattr(self, "_by_section"):
            self._by_section: dict[tuple[int, int], list[int]] = {}
            for q, (rd, sc, _lid) in enumerate(self.net.keys):
                self._by_section.setdefault((rd, sc), []).append(q)
        return self._by_section.get((road, sec), [])

    def _meet_following(self, i, d, start, placed, reserved) -> bool:
        net, k, path = self.net, self.target, self.target_lanes
        half = 0.5 * self.length[i]
        for gap in (20.0, 25.0, 30.0, 35.0, 40.0, 45.0, 50.0):
            lane, p, chain = int(self.lane[k]), float(self.p[k]) - gap, []
            while p < 0.0:
                preds = sorted(net.predecessors[lane], key=lambda q: (net.region[q] != -1, q))
                chain.insert(0, lane)
                lane = preds[0]
                p += net.length[lane]
            if self._spot_free(lane, p, half, placed, reserved):
                self.lane[i], self.p[i] = lane, p
                self.routes[i] = chain + list(path[1:])
                self.v0[i] = 1.4 * self.v0[k]
                self.headway[i] = 0.8
                return True
        return False

    def _meet_crossing(self, i, d, start, placed, reserved) -> bool:
        net, path = self.net, self.target_lanes
        half = 0.5 * self.length[i]
        region = net.region
        entries = [j for j in range(1, len(path))
                   if region[path[j]] != -1 and region[path[j - 1]] == -1 and start[j] >= 20.0]
        on_path = set(path)
        for j in sorted(entries, key=lambda j: (abs(start[j] - d), j)):
            r = int(region[path[j]])
            jend = j
            while jend < len(path) and region[path[jend]] == r:
                jend += 1
            prev = path[j - 1]
            _, _, _, h_t, _ = net.pose(np.array([prev]), np.array([net.length[prev]]))
            # points of the target's passage through the region (and its exit lane)
            pl = np.array(path[j:jend + 1], dtype=np.int64)
            qs = [np.arange(0.0, net.length[q], 1.0) for q in pl]
            px, py, *_ = net.pose(np.repeat(pl, [len(q) for q in qs]), np.concatenate(qs))
            cands = []
            for a in range(len(net.keys)):
                if region[a] != -1 or a in on_path or not any(
                        region[s] == r for s in net.successors[a]):
                    continue
                ax, ay, _, h_a, _ = net.pose(np.array([a]), np.array([net.length[a]]))
                dh = math.radians(float(_wrap_deg(h_a[0] - h_t[0])))
                if math.cos(dh) > 0.5:  # same direction as the target: would see its back
                    continue
                # the target must pass in front of the stop line, close by
                ha = math.radians(float(h_a[0]))
                fwd = (px - ax[0]) * math.cos(ha) + (py - ay[0]) * math.sin(ha)
                near = np.hypot(px - ax[0], py - ay[0])[fwd > 1.0]
                if len(near) == 0 or near.min() > 12.0:
                    continue
                cands.append((abs(math.sin(dh)) < 0.7, round(float(near.min())), a))
            for *_score, a in sorted(cands):
                passage = self._straightest_passage(a, r)
                if passage is None:
                    continue
                for back in (12.0, 16.0, 20.0, 24.0, 10.0):
                    p = net.length[a] - back
                    if self._spot_free(a, p, half, placed, reserved):
                        self.lane[i], self.p[i], self.routes[i] = a, p, passage
                        self.hold[i] = (float(start[jend]) if jend < len(start) else np.inf,
                                        self.cfg.crossing_max_wait_s, False)
                        reserved.setdefault(a, []).append((p, float(net.length[a])))
                        return True
        return False

    def _straightest_passage(self, a: int, r: int) -> list[int] | None:
        """Lanes from a's end through region r to the first lane after it, turning
        least; None when there is none."""
        net = self.net
        _, _, _, h0, _ = net.pose(np.array([a]), np.array([net.length[a]]))
        best = None
        stack = [[s] for s in net.successors[a] if net.region[s] == r]
        while stack:
            seq = stack.pop()
            last = seq[-1]
            if net.region[last] != r:
                _, _, _, h1, _ = net.pose(np.array([last]), np.array([0.0]))
                turn = abs(float(_wrap_deg(h1[0] - h0[0])))
                if best is None or (turn, seq) < best:
                    best = (turn, seq)
                continue
            if len(seq) < 12:
                stack.extend([*seq, s] for s in net.successors[last] if s not in seq)
        return None if best is None else best[1]

    # ------------------------------------------------------------------ stepping
    def _extend_routes(self, horizon_m: float) -> None:
        net, rng = self.net, self.rng
        for i in range(self.n):
            if self.parked[i]:
                continue
            r = self.routes[i]
            ahead = net.length[self.lane[i]] - self.p[i] + sum(net.length[j] for j in r)
            while ahead < horizon_m:
                last = r[-1] if r else int(self.lane[i])
                nxt = int(rng.choice(net.successors[last]))
                r.append(nxt)
                ahead += net.length[nxt]

    def step(self) -> None:
        """Advance the traffic by one step of `config.step_s` seconds."""
        net, cfg, idm = self.net, self.cfg, self.cfg.idm
        dt = cfg.step_s
        n = self.n
        self._extend_routes(cfg.lookahead_m + 150.0)
        if self.hold:  # release observers waiting for the target
            k = self.target
            hop = min(self._target_hops, len(self._path_start) - 1)
            done = self._path_start[hop] + self.p[k]
            for i, (dist, t_max, _stand) in list(self.hold.items()):
                if done >= dist or self.t >= t_max or self.target_arrived_t is not None:
                    del self.hold[i]
        occ: dict[int, list[tuple[float, int]]] = {}
        for i in range(n):
            if self.parked[i]:  # beside its lane, not in it: nobody's leader
                continue
            occ.setdefault(int(self.lane[i]), []).append((float(self.p[i]), i))
        gap = np.full(n, np.inf)
        lead_v = np.zeros(n)
        candidates: list[tuple[int, int, int]] = []  # (region, vehicle, index in path of entry)
        region = net.region
        for i in range(n):
            if self.parked[i]:
                gap[i] = 0.0
                continue
            li = int(self.lane[i])
            path = [li, *self.routes[i]]
            off = -float(self.p[i])
            half_i = 0.5 * self.length[i]
            best, best_v = np.inf, 0.0
            for k, lane in enumerate(path):
                if off - half_i > min(best, cfg.lookahead_m):
                    break
                r = int(region[lane])
                if k > 0 and r != -1 and region[path[k - 1]] != r and i not in self.holds[r]:
                    # stop line at the entry of a region we do not hold
                    g = off - half_i
                    if g < best:
                        best, best_v = g, 0.0
                        if off <= cfg.queue_window_m and i not in self.hold:
                            candidates.append((r, i, k))
                    break
                for pj, j in occ.get(lane, ()):
                    if j == i or (k == 0 and pj <= self.p[i]):
                        continue
                    g = off + pj - half_i - 0.5 * self.length[j]
                    if g < best:
                        best, best_v = g, self.v[j]
                off += net.length[lane]
            if i in self.hold and self.hold[i][2]:
                best = 0.0  # stands where it is
            gap[i], lead_v[i] = best, best_v
        self._grant(candidates, occ)
        # IDM (Treiber et al. 2000)
        v = self.v
        v0 = self.v0.copy()
        if self.target is not None:
            per, ph, base = self._spd
            v0[self.target] = base * (1 + cfg.target_speed_variation
                                      * math.sin(2 * math.pi * self.t / per + ph))
        sqrt_ab = math.sqrt(idm.max_accel_mps2 * idm.comfort_decel_mps2)
        s_star = idm.min_gap_m + np.maximum(
            0.0, v * self.headway + v * (v - lead_v) / (2 * sqrt_ab))
        s = np.maximum(gap, 0.05)
        acc = idm.max_accel_mps2 * (1 - (v / v0) ** idm.delta - (s_star / s) ** 2)
        acc = np.clip(acc, -idm.max_decel_mps2, idm.max_accel_mps2)
        v_new = v + acc * dt
        dp = np.where(v_new >= 0, v * dt + 0.5 * acc * dt * dt,
                      np.where(acc < 0, -v * v / (2 * np.minimum(acc, -1e-9)), 0.0))
        dp = np.maximum(dp, 0.0)
        # never drive past a stop line or into the leader
        dp = np.minimum(dp, np.maximum(gap, 0.0))
        dp[self.parked] = 0.0
        v_new[self.parked] = 0.0
        self.v = np.maximum(v_new, 0.0)
        self.p = self.p + dp
        self.t = round(self.t + dt, 9)
        self._advance_lanes()

    def _grant(self, candidates, occ) -> None:
        """Release regions left behind, queue candidates, grant what can be granted."""
        net = self.net
        for r, holders in enumerate(self.holds):
            for i in list(holders):
                in_r = net.region[self.lane[i]] == r
                passage, exit_lane, entered = holders[i]
                if in_r and not entered:
                    holders[i] = (passage, exit_lane, True)
                elif entered and not in_r and self.p[i] > 0.5 * self.length[i] + 0.5:
                    del holders[i]
        now = {(r, i) for r, i, _ in candidates}
        for key in list(self.queue_since):
            if key not in now:
                del self.queue_since[key]
        for r, i, _ in candidates:
            self.queue_since.setdefault((r, i), self.t)
        by_region: dict[int, list[tuple[float, int, int]]] = {}
        for r, i, k in candidates:
            by_region.setdefault(r, []).append((self.queue_since[(r, i)], i, k))
        for r in sorted(by_region):
            holders = self.holds[r]
            waiting: list[tuple[int, ...]] = []  # passages of earlier candidates kept out
            for _since, i, k in sorted(by_region[r]):
                path = [int(self.lane[i]), *self.routes[i]]
                k2 = k
                while k2 < len(path) and net.region[path[k2]] == r:
                    k2 += 1
                passage = tuple(path[k:k2])
                exit_lane = path[k2] if k2 < len(path) else -1
                if any(net.paths_conflict(passage, h[0]) for h in holders.values()):
                    waiting.append(passage)
                    continue
                if any(net.paths_conflict(passage, w) for w in waiting):
                    continue
                ahead = sum(self.length[j] + self.cfg.exit_margin_m
                            for j, h in holders.items() if h[1] == exit_lane)
                if self._room_after(i, k2, occ, ahead):
                    holders[i] = (passage, exit_lane, False)
                    del self.queue_since[(r, i)]

    def _room_after(self, i: int, k2: int, occ, ahead_m: float) -> bool:
        """Is there free road for vehicle i (its length + margin, after `ahead_m` metres
        promised to earlier holders) on its path from index k2 (the region's exit) on?"""
        net = self.net
        path = [int(self.lane[i]), *self.routes[i]]
        need = self.length[i] + self.cfg.exit_margin_m + ahead_m
        off = 0.0
        while k2 < len(path) and off < need:
            lane = path[k2]
            if net.region[lane] != -1:
                return True  # a further region follows at once (not in the towns we know)
            rears = [pj - 0.5 * self.length[j] for pj, j in occ.get(lane, ())]
            if rears:
                return off + min(rears) >= need
            off += net.length[lane]
            k2 += 1
        return True

    def _advance_lanes(self) -> None:
        net = self.net
        for i in np.flatnonzero(self.p >= net.length[self.lane]):
            i = int(i)
            while self.p[i] >= net.length[self.lane[i]]:
                r = self.routes[i]
                if not r:
                    r.append(int(self.rng.choice(net.successors[self.lane[i]])))
                nxt = r[0]
                reg = net.region[nxt]
                if reg != -1 and net.region[self.lane[i]] != reg and i not in self.holds[reg]:
                    self.p[i] = net.length[self.lane[i]] - 1e-6  # hard stop at the line
                    self.v[i] = 0.0
                    break
                self.p[i] -= net.length[self.lane[i]]
                self.lane[i] = r.pop(0)
                if i == self.target:
                    self._target_hops += 1
        if self.target is not None and self.target_arrived_t is None:
            k = self.target
            dl, dp = self.dest
            if self.lane[k] == dl and self.p[k] >= dp:
                self.target_arrived_t = self.t

    # ------------------------------------------------------------------ output
    def lateral_offsets(self) -> np.ndarray:
        """(N,) lateral offsets from the lane centre, metres (the target's wobble, the
        parked cars' roadside offsets)."""
        out = np.zeros(self.n)
        if self.target is not None:
            a = self.cfg.target_wobble_m
            p1, p2, f1, f2 = self._wob
            w = 0.7 * math.sin(2 * math.pi * self.t / p1 + f1) + 0.3 * math.sin(
                2 * math.pi * self.t / p2 + f2)
            out[self.target] = a * w
        out[self.parked] = self.park_lat[self.parked]
        return out

    def frame(self) -> dict[str, np.ndarray]:
        """The current state of every vehicle, as columns (CARLA world, metres, degrees).

        Keys: vehicle_id, x, y, z, yaw, speed, road_id, section_id, lane_id, s.
        """
        x, y, z, yaw, s = self.net.pose(self.lane, self.p, self.lateral_offsets())
        road, sec, lid = self.net.lane_keys(self.lane)
        return {"vehicle_id": self.ids, "x": x, "y": y, "z": z, "yaw": yaw,
                "speed": self.v.copy(), "road_id": road, "section_id": sec,
                "lane_id": lid, "s": s}


def _nearest_lane(net: LaneNetwork, x: float, y: float, free_only: bool = False):
    """(lane index, progress) of the nearest sample of a network lane to (x, y)."""
    lanes = np.searchsorted(net.base, net._g, side="right") - 1
    ok = np.ones(len(lanes), dtype=bool) if not free_only else net.region[lanes] == -1
    d = np.hypot(net._x - x, net._y - y)
    d[~ok] = np.inf
    j = int(np.argmin(d))
    lane = int(lanes[j])
    p = float(net._g[j] - net.base[lane])
    return lane, float(np.clip(p, 0.5, net.length[lane] - 0.5))
