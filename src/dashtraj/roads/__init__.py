"""The road network: OpenDRIVE reader, CARLA-style waypoints, lane graph and routing.

Knows nothing of cameras or vehicles. Everything is in CARLA's world frame.
"""

from dashtraj.roads.map import Lane, LaneProjection, RoadMap, Waypoint
from dashtraj.roads.opendrive import OpenDriveWarning, parse_opendrive, read_opendrive
from dashtraj.roads.types import LaneType, Location, Rotation, Transform


def load_map(path) -> RoadMap:
    """Read and index an OpenDRIVE file (CARLA frame); same as `RoadMap.from_file`."""
    return RoadMap.from_file(path)


__all__ = [
    "Lane",
    "LaneProjection",
    "LaneType",
    "Location",
    "OpenDriveWarning",
    "RoadMap",
    "Rotation",
    "Transform",
    "Waypoint",
    "load_map",
    "parse_opendrive",
    "read_opendrive",
]
