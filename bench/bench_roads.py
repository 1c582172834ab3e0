"""Road-layer benchmark: map queries side by side with CARLA's own `carla.Map`, then routes.

Run: ``python bench/bench_roads.py [--map PATH] [--json] [--routes N]`` (default map:
../shared/maps/carla/Town10HD.xodr, else the built-in town10).

First peer, `carla.Map` (the ``carla`` client from PyPI builds CARLA's C++ map from
OpenDRIVE text, no server needed; in the dev extra): each operation is timed for
dashtraj and for CARLA in alternation in the same run (medians of repeats), and the
ratio dashtraj / CARLA is printed beside the issue's target:

- load + index: read the file and build the map with its spatial index
  (`RoadMap.from_file` + the Driving-lane index; ``carla.Map(name, text)``, which
  builds CARLA's R-tree) - target ≤ 1.0×;
- one `get_waypoint` call (per call, over 1,000 random points in the map's extent,
  with a z as CARLA always has one) - target ≤ 2.0×;
- 10,000 points vectorised (`RoadMap.project`) per point, against CARLA's single
  call per point - target ≥ 5× faster (ratio ≤ 0.2);
- `generate_waypoints(2.0)` - target ≤ 1.0×; `get_topology()` and `Waypoint.next(2.0)`
  (per call, over 1,000 waypoints) - reported.

Further peers, measured in the same run when installed (``pip install -e '.[bench]'``):
- pyxodr (pure-Python OpenDRIVE reader): RoadNetwork + every lane centre line at
  1 m resolution, the nearest equivalent of our load-and-index;
- roadgen (Rust reader): ``read_opendrive(path, sampling=1.0)``;
- CARLA's GlobalRoutePlanner: CARLA's router needs a running server, so its
  algorithm is re-implemented here on our RoadMap exactly as CARLA's
  ``agents/navigation/global_route_planner.py`` builds it (nodes keyed by
  positions rounded to 1 m, edge weight = number of 2 m waypoints, zero-cost lane
  changes, ``networkx.astar_path`` with a Euclidean heuristic in metres). Besides
  time, the bench counts how often its route is longer than ours.
"""

from __future__ import annotations

import argparse
import itertools
import json
import statistics
import sys
import time
from pathlib import Path

import networkx as nx
import numpy as np

from dashtraj.roads import LaneType, Location, RoadMap


def _alternate(ours, theirs, repeats: int, per: int = 1) -> tuple[float, float]:
    """Median seconds (divided by `per`) of `ours` and `theirs`, run in alternation so
    that both see the same machine load."""
    a, b = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        ours()
        t1 = time.perf_counter()
        theirs()
        t2 = time.perf_counter()
        a.append((t1 - t0) / per)
        b.append((t2 - t1) / per)
    return statistics.median(a), statistics.median(b)


def _carla_side_by_side(path: Path, res: dict) -> list[tuple[str, str, float, float, str]]:
    """Time dashtraj against carla.Map on the same map; rows (name, unit, ours, carla, target)."""
    import carla

    text_of = path.read_text
    name = path.stem
    rows = []
    _load_ours(path)
    carla.Map(name, text_of())
    ours_t, carla_t = _alternate(lambda: _load_ours(path), lambda: carla.Map(name, text_of()), 15)
    rows.append(("load + index", "ms", ours_t * 1e3, carla_t * 1e3, "≤ 1.0×"))

    m = _load_ours(path)
    cm = carla.Map(name, text_of())
    rng = np.random.default_rng(7)
    x0, y0, x1, y1 = m.extent
    pts = np.column_stack([rng.uniform(x0, x1, 1000), rng.uniform(y0, y1, 1000)])
    ours_locs = [Location(float(x), float(y), 0.0) for x, y in pts]
    ours_xy = [(float(x), float(y)) for x, y in pts]
    carla_locs = [carla.Location(float(x), float(y), 0.0) for x, y in pts]
    m.get_waypoint(ours_locs[0])
    m.get_waypoint(ours_xy[0])
    gw = m.get_waypoint
    cgw = cm.get_waypoint
    ours_t, carla_t = _alternate(lambda: [gw(p) for p in ours_locs],
                                 lambda: [cgw(p) for p in carla_locs], 7, per=len(pts))
    rows.append(("get_waypoint, one call (x, y, z)", "µs", ours_t * 1e6, carla_t * 1e6, "≤ 2.0×"))
    ours_t, carla_t = _alternate(lambda: [gw(p) for p in ours_xy],
                                 lambda: [cgw(p) for p in carla_locs], 7, per=len(pts))
    rows.append(("get_waypoint, one call (x, y)", "µs", ours_t * 1e6, carla_t * 1e6, "≤ 2.0×"))
    # Answers: the same lane as CARLA's (bar exact ties between overlapping lanes).
    same = sum((w.road_id, w.lane_id) == (c.road_id, c.lane_id)
               for w, c in zip([gw(p) for p in ours_locs], [cgw(p) for p in carla_locs],
                               strict=True))
    res["carla_same_lane_fraction"] = same / len(pts)

    big = np.column_stack([rng.uniform(x0, x1, 10_000), rng.uniform(y0, y1, 10_000)])
    m.project(big)
    ours_t, carla_t = _alternate(lambda: m.project(big),
                                 lambda: [cgw(p) for p in carla_locs], 7)
    rows.append(("10,000 points vectorised, per point", "µs", ours_t / 10_000 * 1e6,
                 carla_t / len(pts) * 1e6, "≤ 0.2× (5× faster)"))

    ours_t, carla_t = _alternate(lambda: m.generate_waypoints(2.0),
                                 lambda: cm.generate_waypoints(2.0), 15)
    rows.append(("generate_waypoints(2.0)", "ms", ours_t * 1e3, carla_t * 1e3, "≤ 1.0×"))
    res["generate_waypoints_count"] = [len(m.generate_waypoints(2.0)),
                                       len(cm.generate_waypoints(2.0))]
    ours_t, carla_t = _alternate(m.get_topology, cm.get_topology, 15)
    rows.append(("get_topology()", "ms", ours_t * 1e3, carla_t * 1e3, "—"))
    wps = m.generate_waypoints(2.0)[:1000]
    cwps = cm.generate_waypoints(2.0)[:1000]
    ours_t, carla_t = _alternate(lambda: [w.next(2.0) for w in wps],
                                 lambda: [w.next(2.0) for w in cwps], 7, per=len(wps))
    rows.append(("Waypoint.next(2.0), one call", "µs", ours_t * 1e6, carla_t * 1e6, "—"))
    return rows


def _median_time(fn, repeats: int) -> float:
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def _load_ours(path: Path) -> RoadMap:
    m = RoadMap.from_file(path)
    m._index(LaneType.Driving)
    return m


def _load_pyxodr(path: Path) -> None:
    from pyxodr.road_objects.network import RoadNetwork

    net = RoadNetwork(str(path), resolution=1.0)
    for road in net.get_roads():
        for section in road.lane_sections:
            for lane in section.lanes:
                _ = lane.centre_line


class GrpPeer:
    """CARLA GlobalRoutePlanner's graph and search, on a dashtraj RoadMap."""

    def __init__(self, m: RoadMap, resolution: float = 2.0):
        self.m = m
        self.graph = nx.DiGraph()
        self.ids: dict[tuple, int] = {}
        self.edge_of_lane: dict[tuple, tuple[int, int]] = {}
        for a, b in m.get_topology():
            la, lb = a.transform.location, b.transform.location
            n1 = self._node((round(la.x), round(la.y), round(la.z)), la)
            n2 = self._node((round(lb.x), round(lb.y), round(lb.z)), lb)
            # Waypoints every `resolution` metres from entry until within resolution of exit.
            count = 0
            w = a
            if la.distance(lb) > resolution:
                nxt = w.next(resolution)
                while nxt:
                    w = nxt[0]
                    if w.transform.location.distance(lb) <= resolution:
                        break
                    count += 1
                    nxt = w.next(resolution)
            self.graph.add_edge(n1, n2, length=count + 1, lane=a.key)  # CARLA: len(path) + 1
            self.edge_of_lane[a.key] = (n1, n2)
        for key, (n1, _) in list(self.edge_of_lane.items()):
            rid, sec, lid = key
            for nid in (lid - 1, lid + 1):
                if nid != 0 and (nid > 0) == (lid > 0) and (rid, sec, nid) in self.edge_of_lane:
                    self.graph.add_edge(n1, self.edge_of_lane[(rid, sec, nid)][1], length=0,
                                        lane=None)

    def _node(self, key, loc) -> int:
        if key not in self.ids:
            self.ids[key] = len(self.ids)
            self.graph.add_node(self.ids[key], vertex=(loc.x, loc.y, loc.z))
        return self.ids[key]

    def route(self, a, b) -> list[int]:
        ea = self.edge_of_lane[a.key]
        eb = self.edge_of_lane[b.key]

        def h(u, v):
            x1, y1, z1 = self.graph.nodes[u]["vertex"]
            x2, y2, z2 = self.graph.nodes[v]["vertex"]
            return float(np.sqrt((x1 - x2) ** 2 + (y1 - y2) ** 2 + (z1 - z2) ** 2))

        path = nx.astar_path(self.graph, ea[0], eb[0], heuristic=h, weight="length")
        return [*path, eb[1]]

    def route_metres(self, path: list[int], lane_length: dict) -> float:
        total = 0.0
        for u, v in itertools.pairwise(path):
            lane = self.graph[u][v]["lane"]
            total += lane_length.get(lane, 0.0) if lane is not None else 0.0
        return total


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(__file__).resolve().parents[1] / ".." / "shared" / "maps" / "carla" / \
        "Town10HD.xodr"
    ap.add_argument("--map", default=str(default))
    ap.add_argument("--routes", type=int, default=1000)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    path = Path(args.map)
    if not path.exists():
        from dashtraj.world.towns import town_path

        path = town_path("town10")
    res: dict = {"map": str(path)}

    # 0. side by side with carla.Map
    try:
        rows = _carla_side_by_side(path, res)
    except ImportError as exc:
        rows = []
        res["carla_error"] = f"{type(exc).__name__}: {exc}"[:200]
    res["carla"] = [{"op": op, "unit": unit, "dashtraj": ours, "carla": theirs,
                     "ratio": ours / theirs, "target": target}
                    for op, unit, ours, theirs, target in rows]

    # 1. load and index
    _load_ours(path)
    res["load_s"] = _median_time(lambda: _load_ours(path), 15)
    for name, fn, reps in (("pyxodr", _load_pyxodr, 3), ("roadgen", None, 9)):
        try:
            if name == "roadgen":
                import roadgen

                def fn(p, _r=roadgen):
                    return _r.read_opendrive(str(p), sampling=1.0)

            fn(path)
            res[f"load_{name}_s"] = _median_time(lambda f=fn: f(path), reps)
        except Exception as exc:  # a peer that is missing or fails is reported, not fatal
            res[f"load_{name}_s"] = None
            res[f"load_{name}_error"] = f"{type(exc).__name__}: {exc}"[:200]

    # 2. 10,000 get_waypoint queries
    m = _load_ours(path)
    rng = np.random.default_rng(0)
    x0, y0, x1, y1 = m.extent
    pts = np.column_stack([rng.uniform(x0, x1, 10_000), rng.uniform(y0, y1, 10_000)])
    res["project_10k_s"] = _median_time(lambda: m.project(pts), 9)
    res["get_waypoints_10k_s"] = _median_time(lambda: m.get_waypoints(pts), 5)
    single = pts[:1000]
    res["get_waypoint_single_1k_s"] = _median_time(
        lambda: [m.get_waypoint(p) for p in single], 3)

    # 3. routes
    g = m.lane_graph()
    wps = m.generate_waypoints(5.0)
    pairs = [(wps[i], wps[j]) for i, j in rng.integers(0, len(wps), size=(args.routes, 2))]
    times = []
    ours_len = []
    for a, b in pairs:
        t0 = time.perf_counter()
        r = g.route(a, b)
        times.append(time.perf_counter() - t0)
        ours_len.append(r.cost_m)
    res["route_median_s"] = statistics.median(times)
    res["route_p95_s"] = float(np.percentile(times, 95))
    t0 = time.perf_counter()
    grp = GrpPeer(m)
    res["grp_build_s"] = time.perf_counter() - t0
    lane_len = {k: g._length[k] for k in g._length}
    gtimes, longer, worse = [], 0, []
    for (a, b), ours in zip(pairs, ours_len, strict=True):
        t0 = time.perf_counter()
        p = grp.route(a, b)
        gtimes.append(time.perf_counter() - t0)
        # Compare whole-lane lengths from lane a's start to lane b's start (GRP's unit).
        theirs = grp.route_metres(p, lane_len)
        mine = ours - g.progress(b.key, b.s) + g.progress(a.key, a.s)
        if theirs > mine + 1.0:
            longer += 1
            worse.append(theirs - mine)
    res["grp_route_median_s"] = statistics.median(gtimes)
    res["grp_routes_longer"] = longer
    res["grp_longer_by_median_m"] = statistics.median(worse) if worse else 0.0

    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    print(f"map: {res['map']}")
    if rows:
        print("dashtraj vs carla.Map (CARLA 0.9.16's C++ map, same run, alternating):")
        print(f"  {'operation':38s} {'dashtraj':>10s} {'carla':>10s}  ratio   target")
        for r in res["carla"]:
            tgt = r["target"]
            if tgt.startswith("≤"):
                bound = float(tgt.split()[1].rstrip("×"))
                tgt += "  met" if r["ratio"] <= bound else "  NOT met"
            print(f"  {r['op']:38s} {r['dashtraj']:8.2f} {r['unit']:2s} {r['carla']:7.2f} "
                  f"{r['unit']:2s} {r['ratio']:5.2f}×  {tgt}")
        print(f"  same lane as CARLA's get_waypoint: {res['carla_same_lane_fraction']:.1%} of "
              "1,000 points; generate_waypoints counts (dashtraj, carla): "
              f"{res['generate_waypoints_count']}")
    else:
        print(f"carla.Map not measured ({res.get('carla_error')})")
    print(f"load + index        {res['load_s'] * 1e3:8.1f} ms  (target ≤ 60 ms)")
    for peer in ("pyxodr", "roadgen"):
        t = res.get(f"load_{peer}_s")
        if t is None:
            print(f"  {peer:8s}          not measured ({res.get(f'load_{peer}_error')})")
        else:
            print(f"  {peer:8s}        {t * 1e3:8.1f} ms  → dashtraj is {t / res['load_s']:.2f}× "
                  "faster" if t > res["load_s"] else
                  f"  {peer:8s}        {t * 1e3:8.1f} ms  → dashtraj is "
                  f"{res['load_s'] / t:.2f}× slower")
    print(f"project 10k points  {res['project_10k_s'] * 1e3:8.1f} ms  (target ≤ 50 ms)")
    print(f"get_waypoints 10k   {res['get_waypoints_10k_s'] * 1e3:8.1f} ms  (Waypoint objects)")
    print(f"get_waypoint ×1k    {res['get_waypoint_single_1k_s'] * 1e3:8.1f} ms  (one at a time)")
    print(f"route median        {res['route_median_s'] * 1e3:8.2f} ms  p95 "
          f"{res['route_p95_s'] * 1e3:.2f} ms  (target median ≤ 2 ms), {args.routes} routes")
    print(f"  CARLA GRP algo    {res['grp_route_median_s'] * 1e3:8.2f} ms  → ratio "
          f"{res['grp_route_median_s'] / res['route_median_s']:.2f}× (GRP / dashtraj); "
          f"graph build {res['grp_build_s']:.2f} s")
    print(f"  GRP routes longer than ours: {res['grp_routes_longer']} of {args.routes} "
          f"(median excess {res['grp_longer_by_median_m']:.1f} m)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
