"""Built-in towns: OpenDRIVE validity, geometric consistency of every lane link,
no dead ends, strong connectivity, determinism, extents, and the cache."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import networkx as nx
import pytest
from lxml import etree

from dashtraj.world.towns import TOWNS, UnknownTownError, build_town, town_path
from dashtraj.world.xodr_writer import Geometry, format_float

POS_TOL_M = 0.01
HDG_TOL_DEG = 0.5

# name -> (roads, junctions, connections, CARLA-frame x span range, y span range)
EXPECTED = {
    "town01": dict(roads=126, junctions=12, connections=96, lanes_per_direction=1,
                   x_span=(370.0, 410.0), y_span=(310.0, 350.0)),
    "town10": dict(roads=262, junctions=9, connections=216, lanes_per_direction=2,
                   x_span=(200.0, 240.0), y_span=(180.0, 220.0)),
}


# --- an independent, minimal reader of what the writer produced ----------------------


@dataclass(frozen=True)
class _Road:
    id: int
    length: float
    junction: int
    geometry: tuple[Geometry, ...]
    lane_offset: float
    lanes: dict[int, tuple[str, float, int | None, int | None]]  # id -> type, width, pred, succ
    pred: tuple[str, int, str | None] | None
    succ: tuple[str, int, str | None] | None


def _parse(text: str) -> tuple[etree._Element, dict[int, _Road]]:
    root = etree.fromstring(text.encode("utf-8"))
    roads: dict[int, _Road] = {}
    for r in root.findall("road"):
        geoms = []
        for g in r.find("planView").findall("geometry"):
            arc = g.find("arc")
            geoms.append(Geometry(float(g.get("s")), float(g.get("x")), float(g.get("y")),
                                  float(g.get("hdg")), float(g.get("length")),
                                  float(arc.get("curvature")) if arc is not None else 0.0))
        lanes = {}
        sections = r.find("lanes").findall("laneSection")
        assert len(sections) == 1
        for lane in sections[0].iter("lane"):
            lid = int(lane.get("id"))
            if lid == 0:
                continue
            width = lane.find("width")
            assert float(width.get("b")) == 0.0
            p = lane.find("link/predecessor")
            s = lane.find("link/successor")
            lanes[lid] = (lane.get("type"), float(width.get("a")),
                          int(p.get("id")) if p is not None else None,
                          int(s.get("id")) if s is not None else None)

        def link(tag: str, r=r):
            e = r.find(f"link/{tag}")
            if e is None:
                return None
            return (e.get("elementType"), int(e.get("elementId")), e.get("contactPoint"))

        roads[int(r.get("id"))] = _Road(
            id=int(r.get("id")), length=float(r.get("length")), junction=int(r.get("junction")),
            geometry=tuple(geoms), lane_offset=float(r.find("lanes/laneOffset").get("a")),
            lanes=lanes, pred=link("predecessor"), succ=link("successor"))
    return root, roads


def _ref_pose(road: _Road, s: float) -> tuple[float, float, float]:
    geo = [g for g in road.geometry if g.s <= s + 1e-9][-1]
    return geo.pose_at(s - geo.s)


def _lane_t(road: _Road, lane_id: int) -> float:
    """Lateral offset of the lane centre from the reference line (left positive)."""
    sign = 1 if lane_id > 0 else -1
    t = road.lane_offset
    for k in range(1, abs(lane_id)):
        t += sign * road.lanes[sign * k][1]
    return t + sign * road.lanes[lane_id][1] / 2


def _lane_pose(road: _Road, lane_id: int, s: float) -> tuple[float, float, float]:
    """Lane-centre pose at s, heading in the lane's driving direction (degrees)."""
    x, y, h = _ref_pose(road, s)
    t = _lane_t(road, lane_id)
    hdg = h if lane_id < 0 else h + math.pi
    return (x - t * math.sin(h), y + t * math.cos(h), math.degrees(hdg))


def _entry(road: _Road, lane_id: int):
    return _lane_pose(road, lane_id, 0.0 if lane_id < 0 else road.length)


def _exit(road: _Road, lane_id: int):
    return _lane_pose(road, lane_id, road.length if lane_id < 0 else 0.0)


def _lane_graph(root, roads: dict[int, _Road]) -> nx.DiGraph:
    """Directed graph of driving lanes (road_id, lane_id) in driving direction, from
    road-level lane links and junction connections."""
    g = nx.DiGraph()
    for road in roads.values():
        for lid, (typ, _w, pred, succ) in road.lanes.items():
            if typ != "driving":
                continue
            g.add_node((road.id, lid))
            for link, other in ((road.succ, succ), (road.pred, pred)):
                if link is None or other is None:
                    continue
                assert link[0] == "road", f"road {road.id}: lane link across a junction link"
                forward = (link is road.succ) == (lid < 0)
                a, b = ((road.id, lid), (link[1], other))
                g.add_edge(*(a, b) if forward else (b, a))
    for j in root.findall("junction"):
        for c in j.findall("connection"):
            inc, con = int(c.get("incomingRoad")), int(c.get("connectingRoad"))
            assert c.get("contactPoint") == "start"
            for ll in c.findall("laneLink"):
                g.add_edge((inc, int(ll.get("from"))), (con, int(ll.get("to"))))
    return g


@pytest.fixture(scope="module", params=sorted(TOWNS))
def town(request):
    text = build_town(request.param)
    root, roads = _parse(text)
    return request.param, text, root, roads, _lane_graph(root, roads)


# --- tests ------------------------------------------------------------------------------


def test_registry_and_unknown_name():
    assert set(TOWNS) == {"town01", "town10"}
    with pytest.raises(UnknownTownError, match="town01, town10"):
        build_town("town99")


def test_deterministic_bytes():
    for name in TOWNS:
        assert build_town(name) == build_town(name)


def test_header_and_counts(town):
    name, _text, root, roads, _g = town
    exp = EXPECTED[name]
    header = root.find("header")
    assert (header.get("revMajor"), header.get("revMinor"), header.get("vendor")) == (
        "1", "4", "dashtraj")
    assert len(roads) == exp["roads"]
    assert len(root.findall("junction")) == exp["junctions"]
    assert len(root.findall("junction/connection")) == exp["connections"]
    junction_ids = {int(j.get("id")) for j in root.findall("junction")}
    for road in roads.values():
        assert road.junction == -1 or road.junction in junction_ids
        assert abs(sum(g.length for g in road.geometry) - road.length) < 1e-6
        for link in (road.pred, road.succ):
            assert link is not None
            if link[0] == "road":
                assert link[1] in roads and link[2] in ("start", "end")
            else:
                assert link[1] in junction_ids and road.junction == -1


def test_lane_counts(town):
    name, _text, _root, roads, _g = town
    n = EXPECTED[name]["lanes_per_direction"]
    for road in roads.values():
        driving = sorted(lid for lid, v in road.lanes.items() if v[0] == "driving")
        if road.junction == -1:
            assert driving == [*range(-n, 0), *range(1, n + 1)]
            types = {v[0] for v in road.lanes.values()}
            assert {"sidewalk", "shoulder"} <= types
            assert all(3.5 <= v[1] <= 4.0 for v in road.lanes.values() if v[0] == "driving")
        else:
            assert driving == [-1]


def _link_errors(roads: dict[int, _Road], g: nx.DiGraph) -> list[str]:
    """Every lane link whose lane ends do not coincide (position, driving heading)."""
    errors = []
    for (ra, la), (rb, lb) in g.edges:
        xa, ya, ha = _exit(roads[ra], la)
        xb, yb, hb = _entry(roads[rb], lb)
        gap = math.hypot(xa - xb, ya - yb)
        dh = abs((ha - hb + 180.0) % 360.0 - 180.0)
        if gap > POS_TOL_M or dh > HDG_TOL_DEG:
            errors.append(f"{(ra, la)} -> {(rb, lb)}: {gap:.4f} m, {dh:.3f} deg apart")
    return errors


def test_every_lane_link_is_geometrically_continuous(town):
    _name, _text, _root, roads, g = town
    assert g.number_of_edges() > 0
    assert _link_errors(roads, g) == []


def test_continuity_checker_catches_a_gap():
    text = build_town("town01")
    root = etree.fromstring(text.encode("utf-8"))
    connector = next(r for r in root.findall("road") if r.get("junction") != "-1")
    geo = connector.find("planView/geometry")
    geo.set("x", str(float(geo.get("x")) + 0.02))  # shift one connecting road by 2 cm
    root2, roads2 = _parse(etree.tostring(root, encoding="unicode"))
    errors = _link_errors(roads2, _lane_graph(root2, roads2))
    assert len(errors) == 2  # into and out of the shifted road
    assert all(f"({connector.get('id')}, -1)" in e for e in errors)


def test_links_name_existing_lanes(town):
    _name, _text, _root, roads, g = town
    for r, lane in g.nodes:
        assert lane in roads[r].lanes and roads[r].lanes[lane][0] == "driving"


def test_no_dead_ends_and_strongly_connected(town):
    _name, _text, _root, roads, g = town
    n_driving = sum(1 for r in roads.values() for v in r.lanes.values() if v[0] == "driving")
    assert g.number_of_nodes() == n_driving
    for node in g.nodes:
        assert g.in_degree(node) >= 1 and g.out_degree(node) >= 1, node
    assert nx.is_strongly_connected(g)


def test_connecting_roads_follow_junction_rules(town):
    """Each connection has one lane link into lane -1; the connecting road's own lane
    links agree with it; no U-turns (the road leaves by another road than it came)."""
    _name, _text, root, roads, _g = town
    for j in root.findall("junction"):
        for c in j.findall("connection"):
            con = roads[int(c.get("connectingRoad"))]
            links = [(int(ll.get("from")), int(ll.get("to"))) for ll in c.findall("laneLink")]
            assert len(links) == 1 and links[0][1] == -1
            assert con.junction == int(j.get("id"))
            assert con.pred[1] == int(c.get("incomingRoad"))
            assert con.lanes[-1][2] == links[0][0]
            assert con.succ[1] != con.pred[1] or con.lanes[-1][3] != -con.lanes[-1][2]


def test_extents_in_carla_frame(town):
    name, _text, _root, roads, _g = town
    xs, ys = [], []
    for road in roads.values():
        for geo in road.geometry:
            for i in range(11):
                x, y, _ = geo.pose_at(geo.length * i / 10)
                xs.append(x)
                ys.append(-y)  # CARLA frame
    exp = EXPECTED[name]
    assert exp["x_span"][0] <= max(xs) - min(xs) <= exp["x_span"][1]
    assert exp["y_span"][0] <= max(ys) - min(ys) <= exp["y_span"][1]
    assert min(xs) >= 0.0 and min(ys) >= 0.0
    centres = [_lane_pose(road, lid, road.length * i / 10)
               for road in roads.values() for lid, v in road.lanes.items()
               if v[0] == "driving" for i in range(11)]
    assert min(c[0] for c in centres) >= 0.0 and max(c[1] for c in centres) <= 0.0


def test_format_float_is_stable():
    assert format_float(-0.0) == "0"
    assert format_float(1.5) == "1.5"
    assert format_float(2.0) == "2"
    with pytest.raises(ValueError):
        format_float(float("nan"))


def test_town_path_caches(tmp_path, monkeypatch):
    p1 = town_path("town01", cache_dir=tmp_path)
    assert p1.read_text(encoding="utf-8") == build_town("town01")
    mtime = p1.stat().st_mtime_ns
    p2 = town_path("town01", cache_dir=tmp_path)
    assert p2 == p1 and p2.stat().st_mtime_ns == mtime
    monkeypatch.setenv("DASHTRAJ_CACHE", str(tmp_path / "env"))
    p3 = town_path("town10")
    assert p3.parent == tmp_path / "env" / "towns" and p3.is_file()
    assert not list(p3.parent.glob(".*.tmp"))


def test_roadmap_reads_towns_without_warnings(town):
    """dashtraj.roads reads each town with no warning; its CARLA-style topology has one
    pair per lane link of ours, and lane centres map back to their own lane."""
    try:
        from dashtraj.roads import RoadMap
    except ImportError:
        pytest.skip("dashtraj.roads.RoadMap is not available")
    _name, text, _root, roads, g = town
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rmap = RoadMap.from_string(text)
        topology = rmap.get_topology()
    assert len(topology) == g.number_of_edges() > 0
    for road in roads.values():
        if road.junction != -1:
            continue
        for lid, (typ, *_rest) in road.lanes.items():
            if typ != "driving":
                continue
            x, y, _h = _lane_pose(road, lid, road.length / 2)
            wp = rmap.get_waypoint((x, -y))  # CARLA frame
            assert (wp.road_id, wp.lane_id) == (road.id, lid)


def test_carla_reads_towns_like_we_do(town):
    """CARLA's own OpenDRIVE parser (carla.Map built client-side, no server) finds the
    same lane links and junctions. Runs only where the `carla` package is installed."""
    carla = pytest.importorskip("carla")
    name, text, root, _roads, g = town
    cmap = carla.Map(name, text)
    assert len(cmap.get_topology()) == g.number_of_edges()
    wps = cmap.generate_waypoints(2.0)
    assert len({w.get_junction().id for w in wps if w.is_junction}) == len(
        root.findall("junction"))
    for w in wps[::25]:
        cur = w
        for _ in range(200):  # drive on: never a dead end
            nxt = cur.next(2.0)
            assert nxt, f"dead end at road {cur.road_id} lane {cur.lane_id}"
            cur = nxt[-1]
