"""Hand-built sightings on the real Town01 for the gating tests (road 12 runs along +x
at y ≈ 199 with lanes -1 (+x) and 1; road 6 and road 4 are the parallel streets)."""

from __future__ import annotations

from dashtraj.trajectory.records import Sighting


def sight(m, t: float, road: int, s: float, lane: int = -1, obs: int = 1, track: int = 1,
          orientation: str = "back", behind_m: float = 10.0) -> Sighting:
    """A sighting on a lane centre at road s, seen by an observer `behind_m` behind it on
    the same road's lane -1 (so Algorithm 1 applies)."""
    v = m.waypoint(road, 0, lane, s).transform.location
    o = m.waypoint(road, 0, -1, max(0.0, s - behind_m)).transform
    return Sighting(t=t, observer_id=obs, observer_x=o.location.x, observer_y=o.location.y,
                    observer_yaw=o.rotation.yaw, x=v.x, y=v.y, orientation=orientation,
                    vehicle_class="car", track_id=track)


def drive(m, t0: float, t1: float, road: int, s0: float, speed: float = 10.0, obs: int = 1,
          track: int = 1, step: float = 0.5) -> list[Sighting]:
    """A track: the target on lane -1 of `road` from s0 at `speed` m/s, t0..t1 s."""
    n = round((t1 - t0) / step) + 1
    return [sight(m, t0 + i * step, road, s0 + speed * i * step, obs=obs, track=track)
            for i in range(n)]
