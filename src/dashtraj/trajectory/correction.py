"""Lane correction of one sighting: the paper's Algorithm 1 (`correct_position`).

A front- or back-facing vehicle seen by a dashcam tells which way it drives
relative to the observer: a vehicle whose *front* the camera sees is oncoming,
so it drives in a lane of the opposite sign to the observer's lane (OpenDRIVE:
negative lane ids drive along the reference line, positive ones against it); a
vehicle whose *back* the camera sees drives the same way, in a lane of the same
sign. When the map-matched lane of the estimated position contradicts that, the
position was pushed across the road centre by a distance or bearing error, and
the sighting is moved to the lane of the other sign at the same road, lane
section and s (paper §II.F, Algorithm 1, `correct_position`).

Departures from the paper's literal pseudo-code:

- Algorithm 1 writes the test with set and XOR operators (``veh.road ∩ ego.road``,
  ``veh.lane ⊕ ego.lane > 0``); we implement its stated intent: same road id,
  and "same sign" / "opposite sign" of the two lane ids.
- "Multiply the lane id by −1" can name a lane that does not exist (a road with
  two lanes one way and one the other, or a non-driving lane). We keep |lane id|
  when that lane exists and is a driving lane, else take the nearest existing
  driving lane on the other side (closest |id|, inner lane on a tie). When the
  other side has no driving lane (a one-way road) the sighting is left alone.
- An unmoved sighting keeps its own estimated (x, y), as the paper returns
  ``(veh.x, veh.y)``; a moved one gets the new lane centre's position.
- Side-facing vehicles are never moved (the paper's §IV: their road id mostly
  differs from the observer's, and the label says nothing about the direction).
"""

from __future__ import annotations

from dataclasses import dataclass

from dashtraj.roads import LaneType, RoadMap, Waypoint
from dashtraj.trajectory.records import Sighting

REASONS: tuple[str, ...] = (
    "moved",
    "consistent",
    "side",
    "different-road",
    "no-lane-on-other-side",
)
"""Why `correct_position` moved a sighting or left it alone (`CorrectedPosition.reason`)."""


@dataclass(frozen=True, slots=True)
class CorrectedPosition:
    """The outcome of lane-correcting one sighting.

    Attributes:
        sighting: the sighting that was corrected.
        before: the waypoint its estimated position map-matches to (nearest
            driving-lane centre).
        observer: the waypoint the observer's position map-matches to.
        after: the waypoint it belongs to after correction (== `before` when not moved).
        x, y: corrected position, CARLA world, metres: the centre of `after` when
            moved, else the sighting's own estimated (x, y).
        moved: True when the lane was switched.
        reason: one of `REASONS`.
    """

    sighting: Sighting
    before: Waypoint
    observer: Waypoint
    after: Waypoint
    x: float
    y: float
    moved: bool
    reason: str


def _other_side_lane(road_map: RoadMap, wp: Waypoint) -> int | None:
    """Lane id on the other side of the road centre at wp's road and section.

    |lane id| is kept if that driving lane exists, else the nearest existing
    driving lane on the other side (closest |id|, the inner one on a tie);
    None when the other side has no driving lane.
    """
    want = -wp.lane_id
    ids = [
        key[2]
        for key, lane in road_map.lanes.items()
        if key[0] == wp.road_id
        and key[1] == wp.section_id
        and (key[2] > 0) == (want > 0)
        and lane.type & LaneType.Driving
    ]
    if not ids:
        return None
    return min(ids, key=lambda lid: (abs(abs(lid) - abs(want)), abs(lid)))


def correct_position(road_map: RoadMap, sighting: Sighting) -> CorrectedPosition:
    """Lane-correct one sighting by its orientation (paper Algorithm 1, by intent).

    Map-match the sighting's estimated position and the observer's position to
    the nearest driving-lane centres. If both lie on the same road: a "front"
    vehicle (oncoming) must be in a lane of the opposite sign to the observer's,
    a "back" vehicle in a lane of the same sign; if not, it is moved to the lane
    of the other sign at the same road, section and s (see the module docstring
    for how a missing lane is handled). "side" sightings, and sightings whose
    road differs from the observer's, are left unchanged.

    Args:
        road_map: the map (CARLA world, metres).
        sighting: one sighting; uses x, y, observer_x, observer_y, orientation.

    Returns:
        `CorrectedPosition` (x, y in CARLA world metres).

    Raises:
        OffRoadError: the map has no driving lane at all.

    Example:
        >>> c = correct_position(town10, sighting)  # doctest: +SKIP
        >>> c.moved, c.after.lane_id  # doctest: +SKIP
        (True, 1)
    """
    veh = road_map.get_waypoint((sighting.x, sighting.y))
    ego = road_map.get_waypoint((sighting.observer_x, sighting.observer_y))

    def unchanged(reason: str) -> CorrectedPosition:
        return CorrectedPosition(sighting, veh, ego, veh, sighting.x, sighting.y, False, reason)

    if sighting.orientation == "side":
        return unchanged("side")
    # Algorithm 1, line 1: "if veh.road ∩ ego.road" -- read as: the same road id.
    if veh.road_id != ego.road_id:
        return unchanged("different-road")
    same_sign = (veh.lane_id > 0) == (ego.lane_id > 0)
    # Algorithm 1: front must be opposite to ego, back the same as ego.
    wrong = same_sign if sighting.orientation == "front" else not same_sign
    if not wrong:
        return unchanged("consistent")
    new_lane = _other_side_lane(road_map, veh)
    if new_lane is None:
        return unchanged("no-lane-on-other-side")
    # Algorithm 1: veh.lane <- veh.lane * -1, same road, section and s.
    after = road_map.waypoint(veh.road_id, veh.section_id, new_lane, veh.s)
    loc = after.transform.location
    return CorrectedPosition(sighting, veh, ego, after, loc.x, loc.y, True, "moved")
