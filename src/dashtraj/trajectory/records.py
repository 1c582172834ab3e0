"""Records of the trajectory layer: one `Sighting` of a vehicle, one `Trajectory`.

Frames and units: every position is in CARLA world coordinates (metres, x and y
of the ground plane, z up); every angle is in degrees, CARLA convention (yaw
positive turning +x toward +y). Times are seconds.

Both records validate themselves on construction and are immutable: a
`Sighting` is a frozen dataclass; a `Trajectory` is frozen and keeps read-only
copies of the arrays it was given.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dashtraj.errors import DashtrajError, InputFormatError

ORIENTATIONS: tuple[str, ...] = ("front", "back", "side")
"""Which side of a vehicle a camera saw (the detector's orientation classes)."""

VEHICLE_CLASSES: tuple[str, ...] = ("car", "truck", "bus", "motorcycle", "bicycle")
"""Vehicle classes a sighting may carry."""


class InvalidTrajectoryError(DashtrajError, ValueError):
    """A trajectory's points or times have the wrong shape or are not finite."""


class EmptyTrajectoryError(InvalidTrajectoryError):
    """A trajectory has no points where at least one is needed; the message names it."""


def _check_finite(name: str, value: float) -> None:
    if not math.isfinite(value):
        raise InputFormatError(f"Sighting.{name} must be a finite number, got {value!r}")


@dataclass(frozen=True, slots=True)
class Sighting:
    """One observation of one vehicle by one observer's dashcam.

    Attributes:
        t: time of the frame, seconds.
        observer_id: id of the observer vehicle whose camera saw it.
        observer_x, observer_y: observer position, CARLA world, metres.
        observer_yaw: observer heading, degrees, CARLA convention (positive
            turns +x toward +y).
        x, y: estimated position of the seen vehicle, CARLA world, metres.
        orientation: which side of the vehicle was seen, one of `ORIENTATIONS`.
        vehicle_class: one of `VEHICLE_CLASSES`.
        track_id: the tracker's id for this vehicle in the observer's video, or None.
        distance: estimated camera-to-vehicle distance, metres (>= 0), or None.
        bearing: signed angle of the vehicle off the camera axis, degrees,
            positive to the right (toward +y when yaw = 0), or None.
        z: estimated height of the seen vehicle, CARLA world, metres, or None.
            When given, map matching is height-aware (a vehicle under a bridge
            matches the road it is on; see `dashtraj.roads.map`).

    Raises:
        InputFormatError: a number is not finite, a distance is negative, or
            orientation / vehicle_class is not one of the allowed names.

    Example:
        >>> s = Sighting(t=1.5, observer_id=3, observer_x=0.0, observer_y=0.0,
        ...              observer_yaw=90.0, x=0.0, y=12.0, orientation="back",
        ...              vehicle_class="car", distance=12.0, bearing=0.0)
        >>> s.orientation
        'back'
    """

    t: float
    observer_id: int
    observer_x: float
    observer_y: float
    observer_yaw: float
    x: float
    y: float
    orientation: str
    vehicle_class: str
    track_id: int | None = None
    distance: float | None = None
    bearing: float | None = None
    z: float | None = None

    def __post_init__(self) -> None:
        for name in ("t", "observer_x", "observer_y", "observer_yaw", "x", "y"):
            _check_finite(name, getattr(self, name))
        if self.orientation not in ORIENTATIONS:
            raise InputFormatError(
                f"Sighting.orientation must be one of {', '.join(ORIENTATIONS)}; "
                f"got {self.orientation!r}"
            )
        if self.vehicle_class not in VEHICLE_CLASSES:
            raise InputFormatError(
                f"Sighting.vehicle_class must be one of {', '.join(VEHICLE_CLASSES)}; "
                f"got {self.vehicle_class!r}"
            )
        if self.distance is not None:
            _check_finite("distance", self.distance)
            if self.distance < 0:
                raise InputFormatError(
                    f"Sighting.distance must be >= 0 metres, got {self.distance!r}"
                )
        if self.bearing is not None:
            _check_finite("bearing", self.bearing)
        if self.z is not None:
            _check_finite("z", self.z)


@dataclass(frozen=True, slots=True, eq=False)
class Trajectory:
    """A polyline a vehicle drove, optionally timed.

    Attributes:
        points: (N, 2) float64, CARLA world, metres, in driving order; N >= 1.
        t: (N,) float64 seconds, one per point, or None.

    The arrays are copied and made read-only, so a Trajectory never changes.
    Equality is by value (same points and same times).

    Raises:
        EmptyTrajectoryError: `points` has no rows.
        InvalidTrajectoryError: wrong shape, or a value is not finite.

    Example:
        >>> tr = Trajectory(np.array([[0.0, 0.0], [3.0, 4.0]]))
        >>> tr.length_m
        5.0
    """

    points: np.ndarray
    t: np.ndarray | None = None

    def __post_init__(self) -> None:
        pts = np.array(self.points, dtype=np.float64, copy=True)
        if pts.ndim != 2 or pts.shape[1] != 2:
            raise InvalidTrajectoryError(
                f"Trajectory.points must have shape (N, 2), got {pts.shape}"
            )
        if pts.shape[0] == 0:
            raise EmptyTrajectoryError("Trajectory.points is empty; a trajectory needs a point")
        if not np.isfinite(pts).all():
            bad = int(np.flatnonzero(~np.isfinite(pts).all(axis=1))[0])
            raise InvalidTrajectoryError(f"Trajectory.points row {bad} is not finite")
        pts.setflags(write=False)
        object.__setattr__(self, "points", pts)
        if self.t is not None:
            t = np.array(self.t, dtype=np.float64, copy=True)
            if t.shape != (pts.shape[0],):
                raise InvalidTrajectoryError(
                    f"Trajectory.t must have shape ({pts.shape[0]},), got {t.shape}"
                )
            if not np.isfinite(t).all():
                bad = int(np.flatnonzero(~np.isfinite(t))[0])
                raise InvalidTrajectoryError(f"Trajectory.t row {bad} is not finite")
            t.setflags(write=False)
            object.__setattr__(self, "t", t)

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Trajectory):
            return NotImplemented
        if not np.array_equal(self.points, other.points):
            return False
        if self.t is None or other.t is None:
            return self.t is None and other.t is None
        return bool(np.array_equal(self.t, other.t))

    __hash__ = None  # type: ignore[assignment]  # mutable-looking arrays: not hashable

    @property
    def length_m(self) -> float:
        """Total arc length of the polyline, metres (0.0 for a single point)."""
        d = np.diff(self.points, axis=0)
        return float(np.sqrt((d * d).sum(axis=1)).sum())

    def resample(self, step_m: float) -> Trajectory:
        """Points every `step_m` metres of arc length from the start, plus the end.

        The new points lie at arc lengths 0, step_m, 2 step_m, ... < length and at
        the length itself, so both endpoints are kept; corners between samples are
        cut. The result depends only on the path's shape, not on how it was
        split into vertices (adding collinear midpoints changes nothing beyond
        rounding). Times, if present, are interpolated linearly in arc length.

        Args:
            step_m: spacing along the path, metres, > 0.

        Returns:
            A new Trajectory (a single point if the path has zero length).

        Raises:
            ValueError: `step_m` is not a positive finite number.

        Example:
            >>> Trajectory(np.array([[0.0, 0.0], [10.0, 0.0]])).resample(4.0).points[:, 0]
            array([ 0.,  4.,  8., 10.])
        """
        if not (math.isfinite(step_m) and step_m > 0):
            raise ValueError(f"step_m must be a positive number of metres, got {step_m!r}")
        pts = self.points
        seg = np.diff(pts, axis=0)
        seg_len = np.sqrt((seg * seg).sum(axis=1))
        keep = np.concatenate(([True], seg_len > 0))  # drop zero-length segments
        pts = pts[keep]
        times = None if self.t is None else self.t[keep]
        s = np.concatenate(([0.0], np.cumsum(seg_len[seg_len > 0])))
        total = float(s[-1])
        if total == 0.0:
            return Trajectory(pts[:1], None if times is None else times[:1])
        n_steps = math.ceil(total / step_m)
        s_new = np.arange(n_steps, dtype=np.float64) * step_m
        # Samples closer than rounding to the end would duplicate it: drop them.
        s_new = np.append(s_new[s_new < total - 1e-9 * step_m], total)
        new_pts = np.column_stack((np.interp(s_new, s, pts[:, 0]), np.interp(s_new, s, pts[:, 1])))
        new_pts[0] = pts[0]
        new_pts[-1] = pts[-1]
        new_t = None if times is None else np.interp(s_new, s, times)
        return Trajectory(new_pts, new_t)
