"""`RoadMap` on hand-written OpenDRIVE: lane centres, widths, sections, borders,
elevation and the OpenDRIVE → CARLA flip, each against values worked out by hand.

Lane centre (CARLA_FACTS): reference line + laneOffset + widths of the lanes between
the lane and the centre + half its own width. CARLA location = (x, −y, z).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from dashtraj.roads import LaneType, Location, RoadMap

TOL_M = 1e-9


def _loc(wp):
    t = wp.transform
    return np.array([t.location.x, t.location.y, t.location.z])


def _yaw_diff(a, b):
    return (a - b + 180.0) % 360.0 - 180.0


# --- lane centres: laneOffset and width polynomials --------------------------------------


@pytest.fixture(scope="module")
def straight(xodr):
    """Road 1 along OpenDRIVE +x, 100 m; laneOffset 0.5 + 0.01 s; lanes +1 (3.5 m),
    -1 (3 + 0.02 ds m), -2 (3 m, sidewalk)."""
    return RoadMap.from_string(xodr.opendrive(xodr.road(
        1, xodr.geometry(0.0, 0.0, 0.0, 0.0, 100.0), 100.0,
        [xodr.section(0.0, xodr.lane(1, (3.5, 0, 0, 0)), xodr.lane(-1, (3.0, 0.02, 0, 0)),
                      xodr.lane(-2, (3.0, 0, 0, 0), type_="sidewalk"))],
        lane_offset=[(0.0, 0.5, 0.01, 0.0, 0.0)])))


@pytest.mark.parametrize("s", [0.0, 10.0, 55.5, 100.0])
def test_lane_centres_follow_offset_and_widths(straight, s):
    off = 0.5 + 0.01 * s
    w1 = 3.0 + 0.02 * s
    # OpenDRIVE t of each centre; CARLA y = -t.
    expect = {1: off + 1.75, -1: off - 0.5 * w1, -2: off - w1 - 1.5}
    widths = {1: 3.5, -1: w1, -2: 3.0}
    for lid, t in expect.items():
        wp = straight.waypoint(1, 0, lid, s)
        np.testing.assert_allclose(_loc(wp), [s, -t, 0.0], atol=TOL_M)
        assert wp.lane_width == pytest.approx(widths[lid], abs=TOL_M)
    assert straight.waypoint(1, 0, -2, s).lane_type == LaneType.Sidewalk


def test_lane_heading_includes_the_lateral_slope(straight):
    # Lane -1's centre t(s) = 0.5 + 0.01 s - (3 + 0.02 s)/2 = -1 + 0 s: no slope;
    # lane +1's t(s) = 2.25 + 0.01 s: tangent atan(0.01), flipped and reversed for +1.
    assert straight.waypoint(1, 0, -1, 30.0).transform.rotation.yaw == pytest.approx(0.0,
                                                                                       abs=1e-9)
    yaw = straight.waypoint(1, 0, 1, 30.0).transform.rotation.yaw
    assert _yaw_diff(yaw, 180.0 - math.degrees(math.atan(0.01))) == pytest.approx(0.0,
                                                                                   abs=1e-9)


def test_get_waypoint_returns_the_lane_centre_and_projection_sides(straight):
    # 0.4 m right of lane -1's centre (CARLA y = 1 + 0.4): right of driving dir +x is +y.
    wp = straight.get_waypoint(Location(42.0, 1.4))
    assert (wp.road_id, wp.section_id, wp.lane_id) == (1, 0, -1)
    assert wp.s == pytest.approx(42.0, abs=1e-6)
    np.testing.assert_allclose(_loc(wp)[:2], [42.0, 1.0], atol=1e-6)
    p = straight.project(np.array([[42.0, 1.4], [42.0, -3.0]]))
    assert p.lateral_m[0] == pytest.approx(0.4, abs=1e-6)
    # Lane +1 drives towards -x: its right is CARLA -y. Its centre is at y = -(2.25 + 0.42).
    assert p.lane_id[1] == 1
    assert p.lateral_m[1] == pytest.approx(3.0 - 2.67, abs=1e-4)
    # Sidewalks only when asked for.
    q = straight.get_waypoint(Location(42.0, 6.0), lane_type=LaneType.Sidewalk)
    assert q.lane_id == -2


# --- several lane sections ----------------------------------------------------------------


@pytest.fixture(scope="module")
def sections(xodr):
    """Road 7, 100 m along +x, sections at s = 0, 40, 70 with widths 3, 3.5 + 0.01 ds
    (ds from the section start) and 4; the middle one adds lane -2; lanes linked."""
    x = xodr
    secs = [
        x.section(0.0, x.lane(1, (3.0, 0, 0, 0), succ=1), x.lane(-1, (3.0, 0, 0, 0), succ=-1)),
        x.section(40.0, x.lane(1, (3.5, 0.01, 0, 0), pred=1, succ=1),
                  x.lane(-1, (3.5, 0.01, 0, 0), pred=-1, succ=-1), x.lane(-2, (2.0, 0, 0, 0))),
        x.section(70.0, x.lane(1, (4.0, 0, 0, 0), pred=1), x.lane(-1, (4.0, 0, 0, 0), pred=-1)),
    ]
    return RoadMap.from_string(x.opendrive(x.road(7, x.geometry(0.0, 0.0, 0.0, 0.0, 100.0),
                                                  100.0, secs)))


def test_section_ids_are_zero_based_document_indices(sections):
    m = sections
    assert sorted(k for k in m.lanes if k[0] == 7) == [
        (7, 0, -1), (7, 0, 1), (7, 1, -2), (7, 1, -1), (7, 1, 1), (7, 2, -1), (7, 2, 1)]
    assert [(m.lanes[(7, k, -1)].s0, m.lanes[(7, k, -1)].s1) for k in range(3)] == [
        (0.0, 40.0), (40.0, 70.0), (70.0, 100.0)]


@pytest.mark.parametrize("s,section,width", [(20.0, 0, 3.0), (45.0, 1, 3.55), (69.0, 1, 3.79),
                                             (85.0, 2, 4.0)])
def test_waypoint_in_each_section(sections, s, section, width):
    m = sections
    wp = m.get_waypoint_xodr(7, -1, s)
    assert (wp.section_id, wp.lane_width) == (section, pytest.approx(width, abs=TOL_M))
    np.testing.assert_allclose(_loc(wp), [s, 0.5 * width, 0.0], atol=TOL_M)
    # get_waypoint finds the same lane of the same section from a point 0.3 m to the
    # right of the centre (along the lane normal: the centre slopes where widths grow).
    yaw = math.radians(wp.transform.rotation.yaw)
    q = _loc(wp)[:2] + 0.3 * np.array([-math.sin(yaw), math.cos(yaw)])
    g = m.get_waypoint(Location(*q))
    assert (g.road_id, g.section_id, g.lane_id) == (7, section, -1)
    assert g.s == pytest.approx(s, abs=1e-6)


def test_next_and_previous_cross_sections(sections):
    m = sections
    wp = m.waypoint(7, 0, -1, 35.0)
    [n] = wp.next(10.0)
    assert (n.section_id, n.lane_id, n.s) == (1, -1, pytest.approx(45.0))
    [n] = wp.next(50.0)
    assert (n.section_id, n.s) == (2, pytest.approx(85.0))
    back = m.waypoint(7, 2, 1, 75.0)  # lane +1 drives towards s = 0
    [p] = back.next(10.0)
    assert (p.section_id, p.s) == (1, pytest.approx(65.0))
    [q] = p.previous(10.0)
    assert (q.section_id, q.s) == (2, pytest.approx(75.0))
    assert m.lanes[(7, 1, -1)].successors == [(7, 2, -1)]
    assert m.lanes[(7, 1, 1)].successors == [(7, 0, 1)]


# --- border instead of width --------------------------------------------------------------


def test_border_gives_outer_edge(xodr):
    x = xodr
    text = x.opendrive(x.road(
        3, x.geometry(0.0, 0.0, 0.0, 0.0, 50.0), 50.0,
        [x.section(0.0, x.lane(1, border=(3.0, 0.02, 0, 0)), x.lane(-1, border=(4.0, 0, 0, 0)))]))
    m = RoadMap.from_string(text)
    for s in (0.0, 25.0, 50.0):
        b = 3.0 + 0.02 * s
        left = m.waypoint(3, 0, 1, s)
        assert left.lane_width == pytest.approx(b, abs=TOL_M)
        np.testing.assert_allclose(_loc(left), [s, -0.5 * b, 0.0], atol=TOL_M)
        right = m.waypoint(3, 0, -1, s)
        assert right.lane_width == pytest.approx(4.0, abs=TOL_M)
        np.testing.assert_allclose(_loc(right), [s, 2.0, 0.0], atol=TOL_M)


# --- elevation ----------------------------------------------------------------------------


def test_waypoint_z_is_the_elevation_cubic(xodr):
    x = xodr
    elev = [(0.0, 2.0, 0.1, 0.001, -1e-5), (60.0, 5.0, -0.05, 0.0, 0.0)]
    m = RoadMap.from_string(x.opendrive(x.road(
        4, x.geometry(0.0, 0.0, 0.0, 0.3, 90.0), 90.0, elevation=elev)))
    for s in (0.0, 12.5, 59.0, 60.0, 80.0, 90.0):
        ds = s if s < 60 else s - 60.0
        z = (2.0 + 0.1 * ds + 0.001 * ds**2 - 1e-5 * ds**3) if s < 60 else 5.0 - 0.05 * ds
        for lid in (-1, 1):
            assert m.waypoint(4, 0, lid, s).transform.location.z == pytest.approx(z, abs=TOL_M)
    assert m.project(np.array([[20 * math.cos(0.3), -20 * math.sin(0.3)]])).z[0] == \
        pytest.approx(2.0 + 2.0 + 0.4 - 0.08, abs=1e-3)


# --- the OpenDRIVE → CARLA flip -----------------------------------------------------------


@pytest.fixture(scope="module")
def north(xodr):
    """Road 2 heading north (hdg = +90°) from the origin, 40 m."""
    return RoadMap.from_string(xodr.opendrive(xodr.road(
        2, xodr.geometry(0.0, 0.0, 0.0, math.pi / 2, 40.0), 40.0)))


def test_north_road_yaws(north):
    right = north.waypoint(2, 0, -1, 10.0).transform
    left = north.waypoint(2, 0, 1, 10.0).transform
    assert right.rotation.yaw == pytest.approx(-90.0, abs=1e-9)
    assert left.rotation.yaw == pytest.approx(90.0, abs=1e-9)
    # OpenDRIVE north is CARLA -y; lane -1 sits right of the reference (east, x > 0).
    np.testing.assert_allclose([right.location.x, right.location.y], [1.75, -10.0], atol=TOL_M)
    np.testing.assert_allclose([left.location.x, left.location.y], [-1.75, -10.0], atol=TOL_M)
    # The forward vector of lane -1 points where s grows.
    fwd = right.get_forward_vector()
    ahead = _loc(north.waypoint(2, 0, -1, 11.0)) - _loc(north.waypoint(2, 0, -1, 10.0))
    np.testing.assert_allclose(fwd[:2], ahead[:2], atol=1e-9)


def test_east_road_lane_minus_one_is_carla_positive_y(straight):
    # OpenDRIVE y < 0 (right of a road along +x) is CARLA y > 0.
    assert straight.waypoint(1, 0, -1, 50.0).transform.location.y > 0
    assert straight.waypoint(1, 0, 1, 50.0).transform.location.y < 0
    assert straight.roads[1].plan_view.evaluate(50.0)[1][0] == 0.0


def test_extent_is_in_the_carla_frame(north):
    x0, y0, x1, y1 = north.extent
    assert (x0, x1) == (pytest.approx(0.0, abs=1e-9), pytest.approx(0.0, abs=1e-9))
    assert (y0, y1) == (pytest.approx(-40.0), pytest.approx(0.0, abs=1e-9))
