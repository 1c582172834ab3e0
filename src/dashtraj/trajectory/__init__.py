"""Trajectory layer: Sighting and Trajectory records, SSPD/Hausdorff metrics, CSV I/O."""

from __future__ import annotations

from dashtraj.trajectory.io import (
    read_sightings,
    read_trajectory,
    write_sightings,
    write_trajectory,
)
from dashtraj.trajectory.metrics import (
    directed_hausdorff,
    hausdorff,
    point_to_polyline_distances,
    spd,
    sspd,
)
from dashtraj.trajectory.records import (
    ORIENTATIONS,
    VEHICLE_CLASSES,
    EmptyTrajectoryError,
    InvalidTrajectoryError,
    Sighting,
    Trajectory,
)

__all__ = [
    "ORIENTATIONS",
    "VEHICLE_CLASSES",
    "EmptyTrajectoryError",
    "InvalidTrajectoryError",
    "Sighting",
    "Trajectory",
    "directed_hausdorff",
    "hausdorff",
    "point_to_polyline_distances",
    "read_sightings",
    "read_trajectory",
    "spd",
    "sspd",
    "write_sightings",
    "write_trajectory",
]
