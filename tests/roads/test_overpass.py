"""Height-aware map queries on a synthetic overpass (the z rule of `dashtraj.roads.map`).

Road 1 runs along OpenDRIVE x at ground level; road 2 runs along OpenDRIVE y and is a
bridge: its elevation profile ramps from 0 to 10 m, stays at 10 m over the crossing
(both roads at s = 100 m) and ramps down again. Near the crossing a point at ground
level must map to road 1 and a point at bridge level to road 2, whichever is nearer in
plan view, in `get_waypoint`, `project`, `candidates` and the HMM, and the answers must
be those of CARLA's own `carla.Map` built from the same OpenDRIVE text.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from dashtraj.roads import Location, RoadMap
from dashtraj.trajectory import Sighting
from dashtraj.trajectory.reconstruct import reconstruct_hmm

BRIDGE_Z = 10.0
# Smoothstep ramp 0 → 10 m over 40 m: z = 10 (3u² − 2u³), u = ds / 40.
_C, _D = 3 * BRIDGE_Z / 40**2, -2 * BRIDGE_Z / 40**3
BRIDGE_ELEVATION = [(0.0, 0.0, 0.0, 0.0, 0.0), (40.0, 0.0, 0.0, _C, _D),
                    (80.0, BRIDGE_Z, 0.0, 0.0, 0.0), (120.0, BRIDGE_Z, 0.0, -_C, -_D),
                    (160.0, 0.0, 0.0, 0.0, 0.0)]


def overpass_xodr(x) -> str:
    ground = x.road(1, x.geometry(0.0, -100.0, 0.0, 0.0, 200.0), 200.0,
                    elevation=[(0.0, 0.0, 0.0, 0.0, 0.0)])
    bridge = x.road(2, x.geometry(0.0, 0.0, -100.0, math.pi / 2, 200.0), 200.0,
                    elevation=BRIDGE_ELEVATION)
    return x.opendrive(ground, bridge)


@pytest.fixture(scope="module")
def overpass(xodr) -> tuple[RoadMap, str]:
    text = overpass_xodr(xodr)
    return RoadMap.from_string(text, name="overpass"), text


def _crossing_points(n: int, seed: int) -> np.ndarray:
    """Plan-view points (CARLA frame) in the 7 m square where the two roads cross."""
    rng = np.random.default_rng(seed)
    return rng.uniform(-3.4, 3.4, size=(n, 2))


def test_the_map_really_has_a_bridge(overpass):
    m, _ = overpass
    assert m.waypoint(2, 0, -1, 100.0).transform.location.z == pytest.approx(BRIDGE_Z)
    assert m.waypoint(2, 0, -1, 60.0).transform.location.z == pytest.approx(5.0)
    assert m.waypoint(1, 0, -1, 100.0).transform.location.z == pytest.approx(0.0)


def test_plan_view_nearest_lane_is_on_the_bridge_but_height_picks_the_ground(overpass):
    m, _ = overpass
    # CARLA (1.75, 1.0): 0 m from road 2 lane -1 in plan view, 0.75 m from road 1 lane -1.
    x, y = 1.75, 1.0
    flat = m.get_waypoint((x, y))
    assert (flat.road_id, flat.lane_id) == (2, -1)  # no z: plan view, as before
    low = m.get_waypoint(Location(x, y, 0.3))
    assert (low.road_id, low.lane_id) == (1, -1)
    assert low.s == pytest.approx(101.75, abs=1e-6)
    assert low.transform.location.z == pytest.approx(0.0)
    high = m.get_waypoint((x, y, BRIDGE_Z + 0.3))
    assert (high.road_id, high.lane_id) == (2, -1)
    assert high.transform.location.z == pytest.approx(BRIDGE_Z)
    # The other direction: CARLA (-1.75, -1.2) is on road 2 lane 1 in plan view.
    low = m.get_waypoint(Location(-1.75, -1.2, 0.0))
    assert (low.road_id, low.lane_id) == (1, 1)
    assert m.get_waypoint(Location(-1.75, -1.2, BRIDGE_Z)).road_id == 2


def test_project_matches_each_point_at_its_own_level(overpass):
    m, _ = overpass
    xy = _crossing_points(400, seed=3)
    low = m.project(np.column_stack([xy, np.full(len(xy), 0.5)]))
    high = m.project(np.column_stack([xy, np.full(len(xy), BRIDGE_Z + 0.5)]))
    assert (low.road_id == 1).all()
    assert (high.road_id == 2).all()
    np.testing.assert_allclose(low.z, 0.0, atol=1e-9)
    np.testing.assert_allclose(high.z, BRIDGE_Z, atol=1e-9)
    # The foot point is the plan-view one on the chosen lane: the same s as a 2-D
    # projection restricted to that road would give (straight roads: s = x or s = -y).
    np.testing.assert_allclose(low.s, np.clip(xy[:, 0] + 100.0, 0, 200), atol=1e-6)
    np.testing.assert_allclose(high.s, np.clip(-xy[:, 1] + 100.0, 0, 200), atol=1e-6)
    # 3-D distances: at most the plan offset from the lane centre and the height.
    assert (low.distance_m <= np.hypot(1.75, 0.5) + 1e-9).all()
    # Without z the plan-view nearest wins, so both roads appear.
    flat = m.project(xy)
    assert set(np.unique(flat.road_id)) == {1, 2}
    # A NaN z is "no z" for that row only.
    mixed = m.project(np.column_stack([xy, np.where(np.arange(len(xy)) % 2 == 0, 0.5, np.nan)]))
    np.testing.assert_array_equal(mixed.road_id[::2], low.road_id[::2])
    np.testing.assert_array_equal(mixed.road_id[1::2], flat.road_id[1::2])
    np.testing.assert_array_equal(mixed.s[1::2], flat.s[1::2])


def test_candidates_are_the_lanes_at_the_points_level(overpass):
    m, _ = overpass
    for x, y in _crossing_points(50, seed=4):
        low = m.candidates((x, y, 0.2), radius_m=6.0)
        high = m.candidates(Location(x, y, BRIDGE_Z + 0.2), radius_m=6.0)
        flat = m.candidates((x, y), radius_m=6.0)
        assert set(low.road_id) == {1} and len(low) == 2
        assert set(high.road_id) == {2} and len(high) == 2
        assert set(flat.road_id) == {1, 2} and len(flat) == 4
        assert (np.diff(low.distance_m) >= 0).all()
        # 3-D distance to the lane-centre point (its z is the road's elevation).
        d3 = np.hypot(np.hypot(low.x - x, low.y - y), low.z - 0.2)
        np.testing.assert_allclose(low.distance_m, d3, atol=1e-9)
    # A bridge 10 m up is 10 m away: within a 12 m radius, beyond an 8 m one.
    assert 2 in set(m.candidates((1.75, 1.0, 0.0), radius_m=12.0).road_id)
    assert 2 not in set(m.candidates((1.75, 1.0, 0.0), radius_m=8.0).road_id)


def _sightings(z: float | None) -> list[Sighting]:
    # A vehicle under the bridge, estimated positions all nearer (in plan view) to the
    # bridge's lane -1 than to its own road 1 lane -1.
    pts = [(1.75, 1.0), (1.7, 0.6), (1.6, 1.2), (1.75, 0.2)]
    return [Sighting(t=0.5 * i, observer_id=7, observer_x=-15.0, observer_y=1.75,
                     observer_yaw=0.0, x=x, y=y, orientation="back", vehicle_class="car",
                     z=z) for i, (x, y) in enumerate(pts)]


def test_hmm_matches_among_lanes_at_the_sightings_level(overpass):
    m, _ = overpass
    uniform = (1 / 3, 1 / 3, 1 / 3)  # orientation carries no information here
    under = reconstruct_hmm(m, _sightings(z=0.5), orientation_probs=uniform)
    assert {w.road_id for w in under.matched} == {1}
    over = reconstruct_hmm(m, _sightings(z=BRIDGE_Z + 0.5), orientation_probs=uniform)
    assert {w.road_id for w in over.matched} == {2}
    flat = reconstruct_hmm(m, _sightings(z=None), orientation_probs=uniform)
    assert {w.road_id for w in flat.matched} == {2}  # plan view alone picks the bridge


def test_overpass_answers_are_carlas(overpass):
    """CARLA's get_waypoint takes the 3-D nearest lane segment (its R-tree of segments
    with z); on the overpass its lane and s must be ours at both levels."""
    carla = pytest.importorskip("carla")
    m, text = overpass
    cm = carla.Map("overpass", text)
    xy = _crossing_points(150, seed=5)
    # Away from exact lane-boundary ties (the two lanes of one road meet at its centre).
    xy = xy[(np.abs(xy[:, 0]) > 0.05) & (np.abs(xy[:, 1]) > 0.05)]
    for level in (0.4, BRIDGE_Z + 0.4, 4.0, 6.5):
        ours = m.project(np.column_stack([xy, np.full(len(xy), level)]))
        for i, (x, y) in enumerate(xy):
            c = cm.get_waypoint(carla.Location(float(x), float(y), float(level)))
            assert (c.road_id, c.lane_id) == (ours.road_id[i], ours.lane_id[i]), (x, y, level)
            assert c.s == pytest.approx(ours.s[i], abs=2e-3)
    # Off the crossing, on the ramp (road 2 at 5 m around s = 140): CARLA and we agree
    # on which road a point 5 m up belongs to, and that it is the ramp.
    for y in (-35.0, -40.0, -45.0):
        c = cm.get_waypoint(carla.Location(1.75, y, 5.0))
        w = m.get_waypoint(Location(1.75, y, 5.0))
        assert (c.road_id, c.lane_id) == (w.road_id, w.lane_id) == (2, -1)
        assert c.s == pytest.approx(w.s, abs=2e-3)
