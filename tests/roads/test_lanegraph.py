"""Routing on the lane graph: A* routes against a brute-force networkx Dijkstra on
the same graph with a virtual source and sink; lane-change costs; route_costs;
unreachable destinations; every map successor kept as an edge."""

from __future__ import annotations

import json
import math

import networkx as nx
import numpy as np
import pytest

from carla_maps import load_carla_map
from dashtraj.errors import NoRouteError
from dashtraj.roads import RoadMap

N_PAIRS = 200


def _xy(wp) -> np.ndarray:
    loc = wp.transform.location
    return np.array([loc.x, loc.y])


@pytest.fixture(scope="module", params=["Town01", "Town10HD"])
def town(request):
    m = load_carla_map(request.param)[0]
    wps = m.generate_waypoints(2.0)
    rng = np.random.default_rng(2024)
    idx = rng.choice(len(wps), size=(N_PAIRS, 2))
    return request.param, m, [(wps[i], wps[j]) for i, j in idx]


def _brute_force(g, a, b) -> float:
    """Shortest cost from waypoint a to waypoint b, by networkx Dijkstra on a copy of
    the lane graph with a virtual source and sink."""
    G = g.graph.copy()
    entries = g._start_entries(a)
    assert entries[0][:4] == (a.key, pytest.approx(g.progress(a.key, a.s)),
                              pytest.approx(g.cost_at(a.key, a.s)), 0.0)
    pb, qb = g.progress(b.key, b.s), g.cost_at(b.key, b.s)
    direct = math.inf
    for key, p_entry, q_entry, cost, _ in entries:
        if key == b.key and pb >= p_entry - 1e-9:
            direct = min(direct, cost + qb - q_entry)
        exit_cost = cost + G.nodes[key]["cost"] - q_entry
        for succ, data in g.graph[key].items():
            if data["kind"] != "follow":
                continue
            w = G.edges["SRC", succ]["weight"] if G.has_edge("SRC", succ) else math.inf
            G.add_edge("SRC", succ, weight=min(w, exit_cost))
    G.add_edge(b.key, "SNK", weight=qb)
    try:
        via = nx.dijkstra_path_length(G, "SRC", "SNK") if "SRC" in G else math.inf
    except nx.NetworkXNoPath:
        via = math.inf
    return min(direct, via)


@pytest.mark.parametrize("turn_cost", [0.0, 8.0])
def test_routes_match_brute_force_dijkstra(town, turn_cost):
    _, m, pairs = town
    g = m.lane_graph(turn_cost_m_per_rad=turn_cost)
    widths = max(ln_w for ln_w in (m.waypoint(*ln.key, 0.5 * (ln.s0 + ln.s1)).lane_width
                                   for ln in m.driving_lanes()))
    n_routes = 0
    for a, b in pairs:
        expect = _brute_force(g, a, b)
        if not math.isfinite(expect):
            with pytest.raises(NoRouteError):
                g.route(a, b)
            continue
        r = g.route(a, b)
        n_routes += 1
        assert r.cost_m == pytest.approx(expect, abs=1e-6), (a, b)
        poly = r.polyline
        assert np.linalg.norm(poly[0] - _xy(a)) <= 0.5
        assert np.linalg.norm(poly[-1] - _xy(b)) <= 0.5
        steps = np.linalg.norm(np.diff(poly, axis=0), axis=1)
        big = steps[steps > 2.0]
        assert len(big) <= r.lane_changes, (a, b, big)
        assert (big <= widths + 2.0).all()
        assert r.length_m <= r.cost_m + 1.0 + 0.01 * r.cost_m
    assert n_routes > 0.9 * len(pairs)


def test_direct_route_ahead_on_the_same_lane(town):
    _, m, _ = town
    g = m.lane_graph()
    lane = max(m.driving_lanes(), key=lambda ln: ln.s1 - ln.s0)
    a = m.waypoint(*lane.key, lane.start_s + (5.0 if lane.forward else -5.0))
    b = m.waypoint(*lane.key, lane.start_s + (25.0 if lane.forward else -25.0))
    r = g.route(a, b)
    expect = g.progress(b.key, b.s) - g.progress(a.key, a.s)
    assert r.cost_m == pytest.approx(expect, abs=1e-9)
    assert r.cost_m == pytest.approx(_brute_force(g, a, b), abs=1e-6)
    assert [leg.key for leg in r.legs] == [lane.key]
    assert r.length_m == pytest.approx(expect, rel=0.01)  # centre-line metres, not road s


def test_lane_change_cost_is_monotone(town):
    name, m, pairs = town
    costs = np.array([[m.lane_graph(c).route_cost(a, b) for a, b in pairs[:60]]
                      for c in (0.0, 5.0, 15.0, 50.0)])
    finite = np.isfinite(costs).all(axis=0)
    assert (np.diff(costs[:, finite], axis=0) >= -1e-9).all()
    if name == "Town01":  # no same-direction neighbours: lane changes never happen
        np.testing.assert_allclose(costs[:, finite], costs[[0]][:, finite].repeat(4, 0),
                                   atol=1e-9)
        assert not any(d["kind"] == "lane_change"
                       for *_, d in m.lane_graph().graph.edges(data=True))


def test_route_costs_equals_route_cost(town):
    _, m, pairs = town
    g = m.lane_graph()
    origin = pairs[0][0]
    dests = [b for _, b in pairs[:80]]
    many = g.route_costs(origin, dests)
    one = np.array([g.route_cost(origin, d) for d in dests])
    np.testing.assert_allclose(many, one, atol=1e-6)
    assert np.isfinite(many).mean() > 0.9
    capped = g.route_costs(origin, dests, max_cost_m=300.0)
    np.testing.assert_array_equal(capped, np.where(one <= 300.0, one, np.inf))


@pytest.mark.parametrize("name,pairs", [("Town01", 160), ("Town10HD", 200)])
def test_every_successor_is_a_follow_edge(name, pairs):
    m = load_carla_map(name)[0]
    g = m.lane_graph()
    follow = [(u, v) for u, v, d in g.graph.edges(data=True) if d["kind"] == "follow"]
    assert len(follow) == len(m.get_topology()) == pairs
    assert set(follow) == {(a.key, b.key) for a, b in m.get_topology()}


def test_unreachable_destination_raises(xodr):
    x = xodr
    m = RoadMap.from_string(x.opendrive(
        x.road(1, x.geometry(0.0, 0.0, 0.0, 0.0, 50.0), 50.0),
        x.road(2, x.geometry(0.0, 0.0, 100.0, 0.0, 50.0), 50.0)))
    g = m.lane_graph()
    a, b = m.waypoint(1, 0, -1, 10.0), m.waypoint(2, 0, -1, 20.0)
    with pytest.raises(NoRouteError, match="no route from road 1 lane -1"):
        g.route(a, b)
    assert g.route_cost(a, b) == math.inf
    assert g.route_costs(a, [b, m.waypoint(1, 0, -1, 30.0)])[0] == math.inf
    assert g.route_costs(a, [b, m.waypoint(1, 0, -1, 30.0)])[1] == pytest.approx(20.0)
    # Behind on the same lane, with no way round: unreachable too.
    with pytest.raises(NoRouteError):
        g.route(m.waypoint(1, 0, -1, 30.0), a)


def test_turn_cost_is_the_heading_change_along_the_lane(town):
    """A lane's turn cost, divided by k, is its total heading change: about the net
    change of its end yaws (CARLA waypoints, an independent computation) or more, and
    equal to it on the lanes that bend one way only (most of them). The polyline's
    turns miss the half samples at the two ends (≤ 1.5° on Town10HD's long curves)."""
    _, m, _ = town
    k = 10.0
    g = m.lane_graph(turn_cost_m_per_rad=k)
    plain = m.lane_graph()
    net, total = [], []
    for ln in m.driving_lanes():
        a, b = m.waypoint(*ln.key, ln.start_s), m.waypoint(*ln.key, ln.end_s)
        net.append(abs((b.transform.rotation.yaw - a.transform.rotation.yaw + 180) % 360 - 180))
        total.append(math.degrees((g.cost_at(ln.key, ln.end_s) - plain.progress(ln.key, ln.end_s))
                                  / k))
        assert g.cost_at(ln.key, ln.start_s) == pytest.approx(0.0, abs=1e-9)
    net, total = np.array(net), np.array(total)
    assert (total >= net - 1.5).all()
    assert np.median(np.abs(total - net)) < 0.01
    assert np.mean(np.abs(total - net) < 0.05) > 0.75
    assert (net > 60).sum() >= 20  # the towns' turning connectors are in the check


def test_turn_cost_prefers_the_route_with_fewer_turns():
    """The built-in town01's grid, southbound at (204, 160) to northbound at (0, 39): round the
    block via x = 104 (four 90° turns, 377.7 m) or straight on to y = 0 (two turns,
    388.0 m). By length the first; at 4 m/rad (π rad saved ≈ 12.6 m > 10.3 m) the
    second."""
    from dashtraj.world.towns import town_path

    m = RoadMap.from_file(town_path("town01"))
    a, b = (203.9, 160.0), (-0.3, 39.0)
    by_length = m.lane_graph().route(a, b)
    by_turns = m.lane_graph(turn_cost_m_per_rad=4.0).route(a, b)
    assert by_length.length_m == pytest.approx(377.7, abs=0.5)
    assert by_turns.length_m == pytest.approx(388.0, abs=0.5)
    assert np.abs(by_length.polyline[:, 0] - 104.0).min() < 2.0   # goes down x = 104
    assert np.abs(by_turns.polyline[:, 0] - 104.0)[by_turns.polyline[:, 1] > 20].min() > 50
    assert by_turns.cost_m == pytest.approx(by_turns.length_m + 4.0 * math.pi, abs=1.0)
    # Costs agree between route, route_cost and route_costs with a turn cost too.
    g = m.lane_graph(turn_cost_m_per_rad=4.0)
    assert g.route_cost(a, b) == pytest.approx(by_turns.cost_m, abs=1e-9)
    assert g.route_costs(g._as_waypoint(a), [b])[0] == pytest.approx(by_turns.cost_m, abs=1e-9)
    for bad in (-1.0, math.inf, math.nan):
        with pytest.raises(ValueError, match="turn_cost_m_per_rad"):
            m.lane_graph(turn_cost_m_per_rad=bad)


def test_map_route_turn_cost_option(capsys):
    """`dashtraj map route --turn-cost` routes with the prior; 0 (the default) by length."""
    from dashtraj.cli import main

    got = {}
    for extra in ([], ["--turn-cost", "4"]):
        assert main(["map", "route", "town01", "--from=203.9,160", "--to=-0.3,39", "--json",
                     *extra]) == 0
        got[len(extra)] = json.loads(capsys.readouterr().out)
    assert got[0]["length_m"] == pytest.approx(377.7, abs=0.5)
    assert got[0]["cost_m"] == pytest.approx(got[0]["length_m"], abs=1e-6)
    assert got[2]["length_m"] == pytest.approx(388.0, abs=0.5)
    assert got[2]["cost_m"] > got[2]["length_m"] + 10.0
    assert main(["map", "route", "town01", "--from=203.9,160", "--to=-0.3,39",
                 "--turn-cost=-2"]) == 2
    assert "--turn-cost" in capsys.readouterr().err
