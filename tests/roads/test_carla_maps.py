"""The real CARLA towns: golden counts and extents (CARLA_FACTS), projection round
trips, next/previous walks, generate_waypoints, side lanes and topology continuity.
Skipped when ``../shared/maps/carla`` is missing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from carla_maps import load_carla_map
from dashtraj.roads import LaneType, Location, RoadMap

pytestmark = pytest.mark.carla_maps

GOLDEN = {
    "Town01": dict(pairs=160, roads=122, junctions=12, driving=124,
                   extent=(-0.06, -0.05, 394.4, 328.6)),
    "Town10HD": dict(pairs=200, roads=108, junctions=9, driving=168,
                     extent=(-112.5, -66.9, 108.1, 136.0)),
}


def _xy(wp) -> np.ndarray:
    loc = wp.transform.location
    return np.array([loc.x, loc.y])


@pytest.fixture(scope="module", params=sorted(GOLDEN))
def town(request) -> tuple[str, RoadMap]:
    return request.param, load_carla_map(request.param)[0]


def test_golden_counts_and_extent(town):
    name, m = town
    g = GOLDEN[name]
    assert len(m.get_topology()) == g["pairs"]
    assert len(m.roads) == g["roads"]
    assert len(m.junctions) == g["junctions"]
    assert len(m.driving_lanes()) == g["driving"]
    np.testing.assert_allclose(m.extent, g["extent"], atol=0.1)


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_loads_without_warnings(name):
    _, caught = load_carla_map(name)
    assert [str(w.message) for w in caught] == []


def _lane_samples(m: RoadMap, rng: np.random.Generator, per_lane: int = 4):
    """(keys, s) on non-junction driving lanes, s ≥ 3 m from the lane ends."""
    keys, ss = [], []
    for lane in m.driving_lanes():
        if lane.junction != -1 or lane.s1 - lane.s0 < 6.5:
            continue
        for s in rng.uniform(lane.s0 + 3.0, lane.s1 - 3.0, per_lane):
            keys.append(lane.key)
            ss.append(float(s))
    return keys, np.array(ss)


def test_sideways_offset_projects_back_to_the_same_lane_and_s(town):
    _, m = town
    rng = np.random.default_rng(7)
    keys, ss = _lane_samples(m, rng)
    pts, widths = [], []
    for key, s in zip(keys, ss, strict=True):
        wp = m.waypoint(*key, s)
        yaw = math.radians(wp.transform.rotation.yaw)
        right = np.array([-math.sin(yaw), math.cos(yaw)])  # right of the driving direction
        w = wp.lane_width
        for sign in (1.0, -1.0):
            pts.append(_xy(wp) + sign * 0.45 * w * right)
            widths.append(sign * 0.45 * w)
    pts = np.array(pts)
    keys2 = [k for k in keys for _ in (0, 1)]
    s2 = np.repeat(ss, 2)
    proj = m.project(pts)
    got = list(zip(proj.road_id.tolist(), proj.section_id.tolist(), proj.lane_id.tolist(),
                   strict=True))
    wrong = [(k, g, s) for k, g, s in zip(keys2, got, s2, strict=True) if k != g]
    assert wrong == []
    np.testing.assert_allclose(proj.s, s2, atol=0.01)
    np.testing.assert_allclose(proj.lateral_m, widths, atol=0.01)
    assert proj.inside.all()
    # The scalar query agrees with the vectorised one.
    for i in range(0, len(pts), 7):
        wp = m.get_waypoint(Location(*pts[i]))
        assert (wp.key, wp.s) == (got[i], pytest.approx(proj.s[i], abs=1e-9))


@pytest.mark.parametrize("name,key,s", [("Town01", (83, 0, 1), 4.133119036546119),
                                        ("Town10HD", (6, 0, -2), 82.02521688159437),
                                        ("Town10HD", (10, 0, 2), 62.433306054343404)])
def test_projection_s_is_exact_at_geometry_joints(name, key, s):
    """Regression: lane samples straddling a line/arc joint gave s off by up to 7 cm
    (fixed in 9eb54f7 by sampling on every breakpoint)."""
    m = load_carla_map(name)[0]
    wp = m.get_waypoint(m.waypoint(*key, s).transform.location)
    assert wp.key == key
    assert wp.s == pytest.approx(s, abs=0.01)


def test_project_to_road_false(town):
    _, m = town
    _, y0, x1, y1 = m.extent
    # A point 20 m outside the map's extent is 20 m off every road.
    far = Location(x1 + 20.0, 0.5 * (y0 + y1))
    assert m.get_waypoint(far, project_to_road=False) is None
    assert m.get_waypoint(far) is not None
    lane = next(ln for ln in m.driving_lanes() if ln.junction == -1)
    wp = m.waypoint(*lane.key, 0.5 * (lane.s0 + lane.s1))
    inside = m.get_waypoint(wp.transform.location, project_to_road=False)
    assert inside is not None and inside.key == wp.key


@pytest.fixture(scope="module")
def random_waypoints(town):
    _, m = town
    wps = m.generate_waypoints(2.0)
    rng = np.random.default_rng(11)
    return m, [wps[i] for i in rng.choice(len(wps), 300, replace=False)]


def _centre_path_m(m: RoadMap, key, s_a: float, s_b: float) -> float:
    """Length of a lane's centre line between road s_a and s_b (fine sampling)."""
    s = np.linspace(s_a, s_b, 200)
    x, y, _, _ = m._lane_pose(key, s)
    return float(np.hypot(np.diff(x), np.diff(y)).sum())


def test_next_is_continuous(random_waypoints):
    """next(2) moves 2 m of road s (as CARLA): the straight-line step is at most the
    lane-centre path it covers (2 m, more on the outside of a curve) + 0.2 m, and at
    least 1 m (never back)."""
    m, wps = random_waypoints
    n_plain = 0
    for wp in wps:
        here = _xy(wp)
        nxt = wp.next(2.0)
        assert nxt, f"dead end after {wp}"
        for n in nxt:
            d = float(np.linalg.norm(_xy(n) - here))
            if n.key == wp.key:
                path = _centre_path_m(m, wp.key, wp.s, n.s)
            else:
                lane = wp.lane
                path = (_centre_path_m(m, wp.key, wp.s, lane.end_s)
                        + _centre_path_m(m, n.key, n.lane.start_s, n.s))
            assert 1.0 <= d <= max(2.0, path) + 0.2, (wp, n, d, path)
            n_plain += d <= 2.2
    assert n_plain > 0.85 * len(wps)  # most steps are on near-straight lanes


def test_walk_200_steps_stays_on_driving_lanes(random_waypoints):
    _, wps = random_waypoints
    rng = np.random.default_rng(3)
    for wp in wps[:10]:
        for _ in range(200):
            nxt = wp.next(2.0)
            assert nxt
            wp = nxt[int(rng.integers(len(nxt)))]
            assert wp.lane_type == LaneType.Driving


def test_previous_mirrors_next(random_waypoints):
    _, wps = random_waypoints
    checked = 0
    for wp in wps:
        lane = wp.lane
        if lane.junction != -1 or not (lane.s0 + 6 < wp.s < lane.s1 - 6):
            continue
        [ahead] = wp.next(5.0)
        back = ahead.previous(5.0)
        assert any(b.key == wp.key and np.linalg.norm(_xy(b) - _xy(wp)) <= 0.1 for b in back)
        checked += 1
    assert checked > 50


def test_generate_waypoints_only_driving_inside_the_road(town):
    _, m = town
    wps = m.generate_waypoints(2.0)
    assert len(wps) > 1000
    assert all(w.lane_type == LaneType.Driving for w in wps)
    assert all(0.0 < w.s < m.roads[w.road_id].length for w in wps)
    # Every driving lane longer than 2 m gets at least one.
    covered = {w.key for w in wps}
    longer = {ln.key for ln in m.driving_lanes() if ln.s1 - ln.s0 > 2.0}
    assert longer <= covered


def test_side_lanes_on_town10_two_lane_roads():
    m = load_carla_map("Town10HD")[0]
    checked = 0
    for rid, road in m.roads.items():
        if road.junction != -1 or len(road.sections) != 1:
            continue
        lanes = road.sections[0].lanes
        if not all(lanes.get(i) is not None and lanes[i].type == "driving"
                   for i in (-2, -1, 1, 2)):
            continue
        s = 0.5 * road.length
        w = {i: m.waypoint(rid, 0, i, s) for i in (-2, -1, 1, 2)}
        assert w[-1].get_right_lane().lane_id == -2
        assert w[-1].get_left_lane().lane_id == 1
        assert w[-2].get_left_lane().lane_id == -1
        assert w[1].get_right_lane().lane_id == 2
        assert w[1].get_left_lane().lane_id == -1
        assert w[2].get_left_lane().lane_id == 1
        # Geometrically: the right lane lies to the right of the driving direction.
        for lid in (-1, 1):
            yaw = math.radians(w[lid].transform.rotation.yaw)
            right = np.array([-math.sin(yaw), math.cos(yaw)])
            r = w[lid].get_right_lane()
            assert float(np.dot(_xy(r) - _xy(w[lid]), right)) > 2.0
            lft = w[lid].get_left_lane()
            assert float(np.dot(_xy(lft) - _xy(w[lid]), right)) < -2.0
        checked += 1
    assert checked >= 10


def test_topology_pairs_touch(town):
    _, m = town
    gaps = []
    for a, b in m.get_topology():
        end = m.waypoint(*a.key, a.lane.end_s)
        gaps.append(float(np.linalg.norm(_xy(end) - _xy(b))))
    assert max(gaps) <= 0.5


def test_projection_picks_the_nearest_segment_exactly(carla_map):
    """The k-d tree search (k nearest midpoints, then an exact ball query where the k-th
    is not far enough) finds the same nearest sample segment as brute force, for
    points on, near and far from the roads."""
    from dashtraj.roads import LaneType

    m = carla_map
    _, seg, _ = m._index(LaneType.Driving)
    rng = np.random.default_rng(11)
    x0, y0, x1, y1 = m.extent
    pts = np.column_stack([rng.uniform(x0 - 30, x1 + 30, 400), rng.uniform(y0 - 30, y1 + 30, 400)])
    chosen = m.project(pts)
    brute = np.array([m._segment_distance(p[None, None, :], seg[None, :]).min() for p in pts])
    # The refined foot point lies on the Hermite curve, not the chord: ≤ 2 cm apart.
    assert np.all(chosen.distance_m <= brute + 0.02)
    assert np.all(chosen.distance_m >= brute - 0.02)
