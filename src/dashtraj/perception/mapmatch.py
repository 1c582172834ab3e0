"""Map-matching of localized detections to CARLA-style waypoints.

A detection's estimated ground position (CARLA world, metres) is matched to the
nearest driving-lane centre: the waypoint (road_id, section_id, lane_id, s) of
`RoadMap.project` (CARLA's ``Map.get_waypoint`` semantics, vectorised) and the signed
lateral offset from that centre (metres, + right of the driving direction). The
paper's lane correction of front/back-facing vehicles (Algorithm 1) stays available
as `lane_correct`, which is `dashtraj.trajectory.correction.correct_position`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dashtraj.trajectory.correction import correct_position as lane_correct

__all__ = ["MapMatch", "lane_correct", "map_match"]


@dataclass(frozen=True, slots=True, eq=False)
class MapMatch:
    """Arrays (N,): road_id, section_id, lane_id (int), s (m from the road start),
    lateral_m (signed offset from the lane centre, m), z (lane-centre elevation, m)."""

    road_id: np.ndarray
    section_id: np.ndarray
    lane_id: np.ndarray
    s: np.ndarray
    lateral_m: np.ndarray
    z: np.ndarray


def map_match(road_map, x, y) -> MapMatch:
    """Waypoints of points (x, y) (arrays (N,), CARLA world metres) on ``road_map``."""
    x = np.asarray(x, np.float64)
    if len(x) == 0:
        e = np.zeros(0, np.int64)
        return MapMatch(e, e, e, np.zeros(0), np.zeros(0), np.zeros(0))
    p = road_map.project(np.column_stack([x, np.asarray(y, np.float64)]))
    return MapMatch(p.road_id.astype(np.int64), p.section_id.astype(np.int64),
                    p.lane_id.astype(np.int64), p.s, p.lateral_m, p.z)
