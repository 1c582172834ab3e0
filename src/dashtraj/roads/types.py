"""CARLA's small value types: LaneType, Location, Rotation, Transform.

Units: metres and degrees, CARLA world frame (x, y, z with z up; yaw positive
turning +x toward +y).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntFlag


class LaneType(IntFlag):
    """OpenDRIVE lane types with carla.LaneType's bit values."""

    NONE = 1
    Driving = 2
    Stop = 4
    Shoulder = 8
    Biking = 16
    Sidewalk = 32
    Border = 64
    Restricted = 128
    Parking = 256
    Bidirectional = 512
    Median = 1024
    Special1 = 2048
    Special2 = 4096
    Special3 = 8192
    RoadWorks = 16384
    Tram = 32768
    Rail = 65536
    Entry = 131072
    Exit = 262144
    OffRamp = 524288
    OnRamp = 1048576
    Any = 0x7FFFFFFE

    @classmethod
    def from_opendrive(cls, name: str) -> LaneType:
        """The flag for an OpenDRIVE ``type`` attribute (case-insensitive); unknown → NONE."""
        return _BY_NAME.get(name.lower(), cls.NONE)

    @classmethod
    def parse(cls, name: str) -> LaneType:
        """A flag from a user-given name such as ``driving`` or ``driving|sidewalk``."""
        flag = cls(0)
        for part in name.split("|"):
            key = part.strip().lower()
            if key == "any":
                return cls.Any
            if key not in _BY_NAME:
                valid = ", ".join(sorted(_BY_NAME)) + ", any"
                raise ValueError(f"unknown lane type {part!r}; valid: {valid}")
            flag |= _BY_NAME[key]
        return flag


_BY_NAME = {m.name.lower(): m for m in LaneType if m.name not in ("Any",)}
_BY_NAME["none"] = LaneType.NONE
_BY_NAME["curb"] = LaneType.Border  # OpenDRIVE 1.7 'curb' lanes are kerbs; CARLA has no such type


@dataclass(frozen=True, slots=True)
class Location:
    """A point in the CARLA world frame, metres."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0

    def distance(self, other: Location) -> float:
        return math.dist((self.x, self.y, self.z), (other.x, other.y, other.z))

    def distance_2d(self, other: Location) -> float:
        return math.hypot(self.x - other.x, self.y - other.y)


@dataclass(frozen=True, slots=True)
class Rotation:
    """Pitch, yaw, roll in degrees, CARLA convention."""

    pitch: float = 0.0
    yaw: float = 0.0
    roll: float = 0.0


@dataclass(frozen=True, slots=True)
class Transform:
    location: Location
    rotation: Rotation

    def get_forward_vector(self) -> tuple[float, float, float]:
        """(cos yaw cos pitch, sin yaw cos pitch, sin pitch), as carla.Transform."""
        y, p = math.radians(self.rotation.yaw), math.radians(self.rotation.pitch)
        return (math.cos(y) * math.cos(p), math.sin(y) * math.cos(p), math.sin(p))


def as_xy(location) -> tuple[float, float]:
    """(x, y) from a Location, carla.Location, or a sequence (x, y[, z])."""
    if hasattr(location, "x"):
        return float(location.x), float(location.y)
    return float(location[0]), float(location[1])


def as_xyz(location) -> tuple[float, float, float | None]:
    """(x, y, z) from a Location, carla.Location or a sequence; z is None when absent.

    A location object always has a z (CARLA's default is 0); a sequence has one
    only when it has three items; a z that is NaN counts as absent.
    """
    if hasattr(location, "x"):
        x, y, z = float(location.x), float(location.y), getattr(location, "z", None)
    else:
        x, y = float(location[0]), float(location[1])
        z = location[2] if len(location) > 2 else None
    if z is not None:
        z = float(z)
        if math.isnan(z):
            z = None
    return x, y, z


def normalize_yaw(yaw_deg):
    """Wrap degrees into (-180, 180]."""
    import numpy as np

    y = np.mod(np.asarray(yaw_deg, dtype=float) + 180.0, 360.0) - 180.0
    return np.where(y == -180.0, 180.0, y)
