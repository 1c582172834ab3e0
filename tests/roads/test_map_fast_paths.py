"""The fast paths answer exactly as the general ones.

`get_waypoint` (one point, plain floats) against `project` (vectorised numpy), and
`generate_waypoints` (one accumulated s sequence for all roads, built at C speed)
against a direct transcription of CARLA's loop, on synthetic maps and CARLA's towns.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from dashtraj.roads import LaneType, Location, RoadMap, Waypoint
from dashtraj.roads.map import _EPS


def _carla_loop(m: RoadMap, distance: float) -> list[tuple]:
    """CARLA's Map::GenerateWaypoints, transcribed: for s = ε; s < L − ε; s += d."""
    out = []
    for road in m.roads.values():
        s = _EPS
        while s < road.length - _EPS:
            k = m.section_at(road, s)
            for lid in sorted(road.sections[k].lanes):
                if m.lanes[(road.id, k, lid)].type == LaneType.Driving:
                    out.append((road.id, k, lid, float(s)))
            s += distance
    return out


@pytest.fixture(scope="module")
def multi_section(xodr) -> RoadMap:
    x = xodr
    secs = [x.section(0.0, x.lane(1), x.lane(-1)),
            x.section(20.0, x.lane(1), x.lane(-1), x.lane(-2), x.lane(-3, type_="sidewalk")),
            x.section(20.000000000000004, x.lane(-1)),  # a section a few ulps long
            x.section(55.5, x.lane(2), x.lane(1, type_="parking"), x.lane(-1))]
    arc = x.geometry(0.0, 0.0, 0.0, 0.2, 90.0, '<arc curvature="0.01"/>')
    return RoadMap.from_string(x.opendrive(
        x.road(1, arc, 90.0, secs),
        x.road(2, x.geometry(0.0, 0.0, 20.0, 0.0, 0.5), 0.5),  # shorter than most steps
        x.road(3, x.geometry(0.0, 0.0, 40.0, 0.0, 33.0), 33.0)))


@pytest.mark.parametrize("distance", [2.0, 0.7, 5.0, 13.3, 1000.0, 0.05])
def test_generate_waypoints_is_carlas_loop_on_a_multi_section_map(multi_section, distance):
    got = [(w.road_id, w.section_id, w.lane_id, w.s) for w in
           multi_section.generate_waypoints(distance)]
    assert got == _carla_loop(multi_section, distance)  # same order, same bits


def test_generate_waypoints_is_carlas_loop_on_carla_towns(carla_map):
    for distance in (2.0, 3.7):
        got = [(w.road_id, w.section_id, w.lane_id, w.s)
               for w in carla_map.generate_waypoints(distance)]
        assert got == _carla_loop(carla_map, distance)


def test_generate_waypoints_rejects_non_positive_distance(multi_section):
    for bad in (0.0, -1.0, math.nan):
        with pytest.raises(ValueError, match="distance must be positive"):
            multi_section.generate_waypoints(bad)


def _points(m: RoadMap, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x0, y0, x1, y1 = m.extent
    return np.column_stack([rng.uniform(x0 - 15, x1 + 15, n), rng.uniform(y0 - 15, y1 + 15, n)])


def test_single_get_waypoint_is_the_vectorised_answer_bit_for_bit(carla_map):
    pts = _points(carla_map, 1500, seed=11)
    p = carla_map.project(pts)
    p3 = carla_map.project(np.column_stack([pts, np.full(len(pts), 0.4)]))
    for i, (x, y) in enumerate(pts.tolist()):
        w = carla_map.get_waypoint((x, y))
        assert (w.road_id, w.section_id, w.lane_id, w.s) == \
            (p.road_id[i], p.section_id[i], p.lane_id[i], p.s[i])
        w3 = carla_map.get_waypoint(Location(x, y, 0.4))
        assert (w3.road_id, w3.section_id, w3.lane_id, w3.s) == \
            (p3.road_id[i], p3.section_id[i], p3.lane_id[i], p3.s[i])
        inside = carla_map.get_waypoint((x, y), project_to_road=False)
        assert (inside is not None) == bool(p.inside[i])


def test_single_get_waypoint_other_lane_types(multi_section):
    pts = _points(multi_section, 300, seed=2)
    for lt in (LaneType.Sidewalk, LaneType.Driving | LaneType.Parking, LaneType.Any):
        p = multi_section.project(pts, lt)
        for i, (x, y) in enumerate(pts.tolist()):
            w = multi_section.get_waypoint((x, y), lane_type=lt)
            assert (w.key, w.s) == ((p.road_id[i], p.section_id[i], p.lane_id[i]), p.s[i])


def test_waypoint_is_an_immutable_record(multi_section):
    m = multi_section
    a = m.waypoint(1, 3, -1, 60.0)
    b = Waypoint(1, 3, -1, 60.0, map=None)
    assert a == b and hash(a) == hash(b)  # the map takes no part in equality
    assert a != m.waypoint(1, 3, -1, 60.5)
    assert (a.road_id, a.section_id, a.lane_id, a.s, a.key) == (1, 3, -1, 60.0, (1, 3, -1))
    assert a.map is m
    assert repr(a) == "Waypoint(road_id=1, section_id=3, lane_id=-1, s=60.0)"
    with pytest.raises(AttributeError):
        a.s = 3.0  # type: ignore[misc]
    with pytest.raises(TypeError):
        _ = a < b
    assert len({a, b, m.waypoint(1, 3, -1, 60.0)}) == 1


def test_project_of_no_points_is_empty(multi_section):
    for shape in ((0, 2), (0, 3)):
        p = multi_section.project(np.zeros(shape))
        assert len(p) == 0 and p.s.shape == (0,)


def test_get_waypoints_is_get_waypoint_per_point(carla_map):
    pts = _points(carla_map, 400, seed=5)
    for project_to_road in (True, False):
        many = carla_map.get_waypoints(pts, project_to_road=project_to_road)
        one = [carla_map.get_waypoint((x, y), project_to_road=project_to_road)
               for x, y in pts.tolist()]
        assert [None if w is None else (w.key, w.s) for w in many] == \
            [None if w is None else (w.key, w.s) for w in one]
        assert all(w is None or (type(w.road_id) is int and type(w.s) is float) for w in many)
