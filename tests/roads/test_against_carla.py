"""dashtraj.roads against CARLA's own OpenDRIVE implementation, on CARLA's real towns.

The `carla` client (PyPI, 0.9.16) builds a `carla.Map` from OpenDRIVE text with no
server, so CARLA's answers can be computed here and compared with ours. Skipped
when `carla` or the maps are missing.
"""

from __future__ import annotations

import numpy as np
import pytest

from carla_maps import carla_map_path, load_carla_map

carla = pytest.importorskip("carla")

TOWNS = ["Town01", "Town10HD"]
_CARLA: dict[str, object] = {}


def _maps(town: str):
    ours = load_carla_map(town)[0]
    if town not in _CARLA:
        _CARLA[town] = carla.Map(town, carla_map_path(town).read_text())
    return ours, _CARLA[town]


def _key(w) -> tuple[int, int, int]:
    return (w.road_id, w.section_id, w.lane_id)


@pytest.mark.parametrize("town", TOWNS)
def test_topology_is_carlas(town):
    ours, theirs = _maps(town)
    assert sorted((_key(a), _key(b)) for a, b in ours.get_topology()) == \
        sorted((_key(a), _key(b)) for a, b in theirs.get_topology())


@pytest.mark.parametrize("town", TOWNS)
def test_generate_waypoints_is_carlas(town):
    ours, theirs = _maps(town)
    assert sorted((_key(w), round(w.s, 6)) for w in ours.generate_waypoints(2.0)) == \
        sorted((_key(w), round(w.s, 6)) for w in theirs.generate_waypoints(2.0))


@pytest.mark.parametrize("town", TOWNS)
def test_transforms_and_next_are_carlas(town):
    ours, theirs = _maps(town)
    wps = ours.generate_waypoints(2.0)
    rng = np.random.default_rng(1)
    for i in rng.integers(0, len(wps), 150):
        w = wps[i]
        c = theirs.get_waypoint_xodr(w.road_id, w.lane_id, w.s)
        a, b = w.transform, c.transform
        assert a.location.x == pytest.approx(b.location.x, abs=1e-3)
        assert a.location.y == pytest.approx(b.location.y, abs=1e-3)
        assert (a.rotation.yaw - b.rotation.yaw + 180.0) % 360.0 - 180.0 == \
            pytest.approx(0.0, abs=1e-3)
        assert w.lane_width == pytest.approx(c.lane_width, abs=1e-4)
        for d in (3.0, 25.0):
            mine = sorted((_key(x), round(x.s, 3)) for x in w.next(d))
            carlas = sorted((_key(x), round(x.s, 3)) for x in c.next(d))
            assert mine == carlas


@pytest.mark.parametrize("town", TOWNS)
def test_get_waypoint_agrees_and_is_never_farther(town):
    """Same lane as CARLA except at exact distance ties between overlapping lanes; where
    the s differ by more than a centimetre, our lane-centre point is the nearer one
    (CARLA's projection is approximate, ours the foot point to ~10 µm)."""
    ours, theirs = _maps(town)
    rng = np.random.default_rng(0)
    x0, y0, x1, y1 = ours.extent
    pts = np.column_stack([rng.uniform(x0, x1, 1500), rng.uniform(y0, y1, 1500)])
    proj = ours.project(pts)
    same = farther = 0
    for i, (x, y) in enumerate(pts):
        c = theirs.get_waypoint(carla.Location(float(x), float(y), 0.0))
        loc = c.transform.location
        d_carla = float(np.hypot(loc.x - x, loc.y - y))
        d_ours = float(proj.distance_m[i])
        if _key(c) == (proj.road_id[i], proj.section_id[i], proj.lane_id[i]):
            same += 1
        else:
            assert d_ours == pytest.approx(d_carla, abs=0.01)  # a tie, not a different answer
        assert d_ours <= d_carla + 0.01
        farther += d_ours > d_carla + 1e-4
    assert same >= 0.97 * len(pts)
    assert farther <= 0.005 * len(pts)
