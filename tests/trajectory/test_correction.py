"""Lane correction (paper Algorithm 1) on constructed sightings on the real Town10HD.

Road 1, section 0 of Town10HD is straight for s in [0, 45] m with driving lanes
-2, -1 (along +s) and 1, 2 (against it); road 21 drives on lanes -2, -1, 4, 5.
Skipped when ``../shared/maps/carla`` is missing.
"""

from __future__ import annotations

import pytest

from dashtraj.roads import RoadMap
from dashtraj.trajectory.correction import REASONS, correct_position
from dashtraj.trajectory.records import Sighting


def sighting_at(m: RoadMap, veh: tuple, obs: tuple, orientation: str) -> Sighting:
    """A sighting placed exactly on lane centres: veh/obs are (road, section, lane, s)."""
    v = m.waypoint(*veh).transform
    o = m.waypoint(*obs).transform
    return Sighting(t=0.0, observer_id=1, observer_x=o.location.x, observer_y=o.location.y,
                    observer_yaw=o.rotation.yaw, x=v.location.x, y=v.location.y,
                    orientation=orientation, vehicle_class="car")


OBS = (1, 0, -1, 15.0)  # observer on lane -1 of straight road 1


@pytest.mark.parametrize(
    ("veh_lane", "orientation", "moved_to", "reason"),
    [
        (-2, "front", 2, "moved"),        # oncoming but on the observer's side: |id| kept
        (-1, "front", 1, "moved"),
        (1, "back", -1, "moved"),         # same direction but on the other side
        (2, "back", -2, "moved"),
        (1, "front", None, "consistent"),
        (2, "front", None, "consistent"),
        (-2, "back", None, "consistent"),
        (-2, "side", None, "side"),
        (1, "side", None, "side"),
    ],
)
def test_same_road_cases(town10, veh_lane, orientation, moved_to, reason):
    s = sighting_at(town10, (1, 0, veh_lane, 30.0), OBS, orientation)
    c = correct_position(town10, s)
    assert c.reason == reason
    assert c.observer.key == (1, 0, -1)
    assert c.before.key == (1, 0, veh_lane)
    assert abs(c.before.s - 30.0) < 1e-6
    if moved_to is None:
        assert not c.moved
        assert c.after == c.before
        assert (c.x, c.y) == (s.x, s.y)
    else:
        assert c.moved
        assert c.after.key == (1, 0, moved_to)
        assert c.after.s == c.before.s  # same road, section and s
        loc = c.after.transform.location
        assert (c.x, c.y) == (loc.x, loc.y)
        # The new lane centre lies across the road centre: a few metres away.
        assert 2.5 < ((c.x - s.x) ** 2 + (c.y - s.y) ** 2) ** 0.5 < 11.0


def test_different_road_unchanged(town10):
    # Vehicle on road 5 (other road), observer on road 1: the paper cannot correct it.
    s = sighting_at(town10, (5, 0, -1, 90.0), OBS, "front")
    c = correct_position(town10, s)
    assert (c.moved, c.reason) == (False, "different-road")
    assert c.before.road_id == 5 and c.observer.road_id == 1


def test_missing_lane_takes_nearest_on_other_side(town10):
    # Road 21 drives on -2, -1 and 4, 5 (1-3 are shoulder and median): lane 1 is no
    # driving lane, so the nearest driving lane on the other side, 4, is taken.
    driving = sorted(k[2] for k, ln in town10.lanes.items()
                     if k[:2] == (21, 0) and ln.type_name == "driving")
    assert driving == [-2, -1, 4, 5]
    length = town10.roads[21].length
    s = sighting_at(town10, (21, 0, -1, 0.6 * length), (21, 0, -1, 0.3 * length), "front")
    c = correct_position(town10, s)
    assert c.moved and c.after.key == (21, 0, 4)


def test_which_ones_move_exactly(town10):
    cases = [((1, 0, -2, 30.0), "front"), ((1, 0, 1, 30.0), "back"), ((1, 0, 1, 30.0), "front"),
             ((1, 0, -2, 30.0), "back"), ((1, 0, -2, 30.0), "side"), ((5, 0, -1, 90.0), "front")]
    moved = [correct_position(town10, sighting_at(town10, v, OBS, o)).moved for v, o in cases]
    assert moved == [True, True, False, False, False, False]
    assert set(REASONS) >= {"moved", "consistent", "side", "different-road"}
