"""Synthetic trips, observers and noisy sightings on a real road map, and a bench.

A trip is a target vehicle driving a route on the lane graph (origin and
destination 300-900 m of route apart; now and then a detour through a random
intermediate place, since drivers do not always take the shortest route),
at a plausible speed (8-14 m/s, slower in junctions, slowly varying), with a
small lateral wobble (±0.3 m), sampled at 10 Hz: the ground-truth `Trajectory`.

Observers with forward dashcams (90° horizontal FOV, as the paper's cameras)
watch it: parked at the roadside on a lane of the route's road, oncoming on the
opposite lane, or following it. Whenever the target is within 15 m and inside
the camera's field of view, an observer's tracker emits at most one `Sighting`
per 0.5-1 s, with the paper's error sources (§II.D, §IV):

- distance: multiplicative (σ 12 %) and additive (σ 1.5 m) Gaussian errors,
  about 2.3 m RMSE under 20 m as reported for Eq. 3;
- class height: a tall vehicle (a van classified as a car) is seen 30-60 %
  farther; drawn once per trip (`SynthTrip.height_factor`);
- bearing: Gaussian, σ 2°;
- wrong side: ~5 % of positions mirrored across the observer's lane axis;
- orientation label from the TRUE pose: the angle between the target's heading
  and the line of sight from the target to the camera; under 45° the camera
  sees its front, over 135° its back, else its side.

The estimated position is observer + D · (cos, sin)(observer yaw + bearing):
signed bearing and the observer's yaw added, as DESIGN.md prescribes (the
paper's Eq. 8/9 lose the sign and the yaw).

Everything random comes from the `numpy.random.Generator` passed in; the same
seed gives identical trips.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dashtraj.errors import DashtrajError, NoRouteError
from dashtraj.roads import RoadMap, Waypoint
from dashtraj.trajectory.correction import _other_side_lane
from dashtraj.trajectory.records import Sighting, Trajectory

SAMPLE_HZ = 10.0
OBSERVER_KINDS: tuple[str, ...] = ("parked", "oncoming", "follower")


@dataclass(frozen=True, slots=True, eq=False)
class ObserverTrack:
    """One observer's poses while it watched a trip.

    Attributes:
        observer_id: id written into its sightings.
        kind: one of `OBSERVER_KINDS`.
        t: (M,) seconds; xy: (M, 2) CARLA world metres; yaw: (M,) degrees.
    """

    observer_id: int
    kind: str
    t: np.ndarray
    xy: np.ndarray
    yaw: np.ndarray


@dataclass(frozen=True, slots=True, eq=False)
class SynthTrip:
    """One synthetic trip: the truth, who watched it, and what they reported.

    Attributes:
        trip_id: index of the trip.
        truth: ground truth at 10 Hz, CARLA world metres, times in seconds.
        sightings: the noisy sightings of the target, in time order.
        observers: the observers' tracks.
        detour: True when the driver went through an intermediate place.
        height_factor: distance factor of the class-height error (1.0 = none).
        wrong_side: how many sightings were mirrored to the wrong side.
    """

    trip_id: int
    truth: Trajectory
    sightings: tuple[Sighting, ...]
    observers: tuple[ObserverTrack, ...]
    detour: bool
    height_factor: float
    wrong_side: int

    def truth_window(self) -> Trajectory:
        """The truth between the first and the last sighting (what sightings can show)."""
        t0, t1 = self.sightings[0].t, self.sightings[-1].t
        t = self.truth.t
        keep = (t >= t0 - 1e-9) & (t <= t1 + 1e-9)
        if keep.sum() < 2:
            return self.truth
        return Trajectory(self.truth.points[keep], t[keep])


def _wrap(a):
    return (np.asarray(a) + 180.0) % 360.0 - 180.0


def _heading_deg(poly: np.ndarray) -> np.ndarray:
    """Unwrapped heading (deg) of a polyline at each vertex (central differences)."""
    g = np.gradient(poly, axis=0)
    return np.degrees(np.unwrap(np.arctan2(g[:, 1], g[:, 0])))


def _arc(poly: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poly, axis=0), axis=1))])


def _dedupe(poly: np.ndarray) -> np.ndarray:
    keep = np.concatenate([[True], np.linalg.norm(np.diff(poly, axis=0), axis=1) > 1e-3])
    return poly[keep]


def _choose_route(road_map: RoadMap, pool: list[Waypoint], rng: np.random.Generator,
                  min_route_m: float, max_route_m: float, detour_prob: float,
                  max_tries: int = 300) -> tuple[np.ndarray, bool]:
    """A route polyline (M, 2) between random places, and whether it is a detour."""
    g = road_map.lane_graph()
    xy = np.array([[w.transform.location.x, w.transform.location.y] for w in pool])
    for _ in range(max_tries):
        o = int(rng.integers(len(pool)))
        straight = np.linalg.norm(xy - xy[o], axis=1)
        far = np.flatnonzero((straight > 0.3 * min_route_m) & (straight < max_route_m))
        if not len(far):
            continue
        d = int(far[rng.integers(len(far))])
        detour = bool(rng.random() < detour_prob)
        try:
            if detour:
                near = np.flatnonzero((straight > 60.0) & (straight < 0.6 * max_route_m))
                if not len(near):
                    continue
                w = int(near[rng.integers(len(near))])
                poly = np.vstack([g.route(pool[o], pool[w]).polyline[:, :2],
                                  g.route(pool[w], pool[d]).polyline[:, :2]])
            else:
                poly = g.route(pool[o], pool[d]).polyline[:, :2]
        except NoRouteError:
            continue
        poly = _dedupe(poly)
        length = _arc(poly)[-1]
        if min_route_m <= length <= max_route_m:
            return poly, detour
    raise DashtrajError(f"{road_map.name}: found no route of {min_route_m:.0f}-{max_route_m:.0f} m "
                        f"in {max_tries} tries")


def _drive(road_map: RoadMap, poly: np.ndarray, rng: np.random.Generator,
           speed_mps: tuple[float, float], wobble_m: float, t0: float = 0.0) -> Trajectory:
    """Drive a polyline: speed profile, lateral wobble, 10 Hz samples → timed Trajectory."""
    s = _arc(poly)
    v0 = rng.uniform(*speed_mps)
    proj = road_map.project(poly)
    in_junction = np.array([road_map.roads[int(r)].junction != -1 for r in proj.road_id])
    v = v0 * (1.0 + 0.08 * np.sin(2 * np.pi * s / rng.uniform(80, 200) + rng.uniform(0, 2 * np.pi)))
    v = np.where(in_junction, 0.6 * v, v)
    k = 15  # smooth speed changes over ~15 m
    v = np.convolve(np.pad(v, k, mode="edge"), np.ones(2 * k + 1) / (2 * k + 1), mode="valid")
    t_of_s = t0 + np.concatenate([[0.0], np.cumsum(np.diff(s) / (0.5 * (v[1:] + v[:-1])))])
    tt = np.arange(t0, t_of_s[-1], 1.0 / SAMPLE_HZ)
    tt = np.append(tt, t_of_s[-1]) if t_of_s[-1] - tt[-1] > 1e-6 else tt
    st = np.interp(tt, t_of_s, s)
    x, y = np.interp(st, s, poly[:, 0]), np.interp(st, s, poly[:, 1])
    h = np.radians(np.interp(st, s, _heading_deg(poly)))
    amp = rng.uniform(0.1, wobble_m)
    lat = amp * np.sin(2 * np.pi * st / rng.uniform(40, 120) + rng.uniform(0, 2 * np.pi))
    # Right of heading h in CARLA's left-handed frame is (-sin h, cos h).
    pts = np.column_stack([x - lat * np.sin(h), y + lat * np.cos(h)])
    return Trajectory(pts, tt)


def _yaw_along(traj: Trajectory) -> np.ndarray:
    return _wrap(_heading_deg(traj.points))


def _observer(road_map: RoadMap, truth: Trajectory, truth_yaw: np.ndarray, tm: float,
              kind: str, obs_id: int, rng: np.random.Generator) -> ObserverTrack | None:
    """An observer of `kind` placed to meet the target around time `tm`."""
    i = int(np.searchsorted(truth.t, tm))
    i = min(i, len(truth) - 1)
    p = truth.points[i]
    wp = road_map.get_waypoint((p[0], p[1]))
    g = road_map.lane_graph()
    if kind == "follower":
        lag = rng.uniform(0.8, 1.3)
        t = truth.t[(truth.t >= tm - rng.uniform(3, 7)) & (truth.t <= tm + rng.uniform(3, 7))]
        tl = np.clip(t - lag, truth.t[0], None)
        xy = np.column_stack([np.interp(tl, truth.t, truth.points[:, 0]),
                              np.interp(tl, truth.t, truth.points[:, 1])])
        yaw = np.interp(tl, truth.t, np.unwrap(truth_yaw, period=360.0))
        return ObserverTrack(obs_id, kind, t, xy, _wrap(yaw))
    other = _other_side_lane(road_map, wp)
    if kind == "parked":
        lane = other if (other is not None and rng.random() < 0.5) else wp.lane_id
        pw = road_map.waypoint(wp.road_id, wp.section_id, lane, wp.s)
        tr = pw.transform
        yaw = tr.rotation.yaw
        off = 0.3 * pw.lane_width  # towards the kerb: right of the driving direction
        x = tr.location.x - off * math.sin(math.radians(yaw))
        y = tr.location.y + off * math.cos(math.radians(yaw))
        t = truth.t
        return ObserverTrack(obs_id, kind, t, np.tile([x, y], (len(t), 1)), np.full(len(t), yaw))
    # oncoming: in the innermost lane of the other side
    if other is None:
        return None
    inner = 1 if other > 0 else -1
    lane = inner if (wp.road_id, wp.section_id, inner) in road_map.lanes else other
    meet = road_map.waypoint(wp.road_id, wp.section_id, lane, wp.s)
    v = rng.uniform(7.0, 12.0)
    before = meet.previous(v * rng.uniform(6, 12))
    after = meet.next(v * rng.uniform(6, 12))
    start = before[int(rng.integers(len(before)))] if before else meet
    end = after[int(rng.integers(len(after)))] if after else meet
    try:
        a = g.route(start, meet).polyline[:, :2] if start != meet else _xy1(meet)
        b = g.route(meet, end).polyline[:, :2] if end != meet else _xy1(meet)
    except NoRouteError:
        return None
    s_meet = _arc(_dedupe(a))[-1]
    poly = _dedupe(np.vstack([a, b]))
    if len(poly) < 2:
        return None
    s = _arc(poly)
    ts = tm + (s - s_meet) / v
    t = truth.t[(truth.t >= ts[0]) & (truth.t <= ts[-1])]
    sq = (t - tm) * v + s_meet
    xy = np.column_stack([np.interp(sq, s, poly[:, 0]), np.interp(sq, s, poly[:, 1])])
    yaw = np.interp(sq, s, _heading_deg(poly))
    return ObserverTrack(obs_id, kind, t, xy, _wrap(yaw))


def _xy1(wp: Waypoint) -> np.ndarray:
    loc = wp.transform.location
    return np.array([[loc.x, loc.y]])


def _sightings(road_map: RoadMap, truth: Trajectory, truth_yaw: np.ndarray,
               obs: ObserverTrack, rng: np.random.Generator, *, height_factor: float,
               range_m: float, fov_deg: float, wrong_side_prob: float,
               ) -> tuple[list[Sighting], int]:
    """What one observer's tracker reports about the target (noisy), and wrong-side count."""
    idx = np.searchsorted(truth.t, obs.t)
    idx = np.clip(idx, 0, len(truth) - 1)
    tgt = truth.points[idx]
    rel = tgt - obs.xy
    dist = np.hypot(rel[:, 0], rel[:, 1])
    bearing = _wrap(np.degrees(np.arctan2(rel[:, 1], rel[:, 0])) - obs.yaw)
    visible = (dist <= range_m) & (np.abs(bearing) <= 0.5 * fov_deg) & (dist > 1.0)
    interval = rng.uniform(0.5, 1.0)
    out: list[Sighting] = []
    wrong = 0
    last = -math.inf
    for j in np.flatnonzero(visible):
        t = float(obs.t[j])
        if t - last < interval:
            continue
        last = t
        # Orientation from the true pose: target heading vs. line of sight target -> camera.
        los = math.degrees(math.atan2(-rel[j, 1], -rel[j, 0]))
        a = abs(float(_wrap(truth_yaw[idx[j]] - los)))
        label = "front" if a < 45.0 else ("back" if a > 135.0 else "side")
        # Eq. 3 distance with class-height, multiplicative and additive errors.
        d_est = dist[j] * height_factor * (1.0 + rng.normal(0.0, 0.12)) + rng.normal(0.0, 1.5)
        d_est = max(d_est, 0.5)
        b_est = float(bearing[j] + rng.normal(0.0, 2.0))
        ox, oy, oyaw = float(obs.xy[j, 0]), float(obs.xy[j, 1]), float(obs.yaw[j])
        # Eq. 9 done right: observer yaw + signed bearing.
        ang = math.radians(oyaw + b_est)
        x, y = ox + d_est * math.cos(ang), oy + d_est * math.sin(ang)
        if rng.random() < wrong_side_prob:
            # Mirror across the observer's lane axis (its lane centre line).
            ow = road_map.get_waypoint((ox, oy)).transform
            u = np.array([math.cos(math.radians(ow.rotation.yaw)),
                          math.sin(math.radians(ow.rotation.yaw))])
            c = np.array([ow.location.x, ow.location.y])
            v = np.array([x, y]) - c
            x, y = c + 2.0 * (v @ u) * u - v
            x, y = float(x), float(y)
            d_est = math.hypot(x - ox, y - oy)
            b_est = float(_wrap(math.degrees(math.atan2(y - oy, x - ox)) - oyaw))
            wrong += 1
        out.append(Sighting(t=t, observer_id=obs.observer_id, observer_x=ox, observer_y=oy,
                            observer_yaw=oyaw, x=x, y=y, orientation=label,
                            vehicle_class="car", track_id=1, distance=float(d_est),
                            bearing=b_est))
    return out, wrong


def make_trips(road_map: RoadMap, n_trips: int, rng: np.random.Generator, *,
               min_route_m: float = 300.0, max_route_m: float = 900.0,
               detour_prob: float = 0.3, speed_mps: tuple[float, float] = (8.0, 14.0),
               wobble_m: float = 0.3, n_observers: tuple[int, int] = (4, 6),
               kind_probs: tuple[float, float, float] = (0.35, 0.4, 0.25),
               range_m: float = 15.0, fov_deg: float = 90.0, wrong_side_prob: float = 0.05,
               tall_prob: float = 0.2, tall_factor: tuple[float, float] = (1.3, 1.6),
               min_sightings: int = 3) -> list[SynthTrip]:
    """Synthetic trips with observers and noisy sightings (see the module docstring).

    Args:
        road_map: the map, CARLA world, metres.
        n_trips: how many trips.
        rng: the random generator; the same seed gives identical trips.
        min_route_m, max_route_m: route length range, metres.
        detour_prob: probability that the driver goes via a random intermediate place.
        speed_mps: range of the base speed, m/s (60 % of it in junctions).
        wobble_m: largest lateral wobble amplitude, metres.
        n_observers: inclusive range of observers per trip.
        kind_probs: probabilities of parked, oncoming, follower observers.
        range_m: sighting range, metres (the paper keeps sightings under 15 m).
        fov_deg: horizontal field of view of the dashcams, degrees.
        wrong_side_prob: share of positions mirrored to the wrong side.
        tall_prob: probability that the target is tall (a van seen as a car).
        tall_factor: range of its distance factor.
        min_sightings: a trip is redrawn until it has at least this many sightings.

    Returns:
        `n_trips` `SynthTrip`s.

    Raises:
        DashtrajError: the map has no route in the length range.

    Example:
        >>> trips = make_trips(town10, 3, np.random.default_rng(0))  # doctest: +SKIP
        >>> len(trips[0].sightings) >= 3  # doctest: +SKIP
        True
    """
    pool = [w for w in road_map.generate_waypoints(10.0) if not w.is_junction]
    if not pool:
        raise DashtrajError(f"{road_map.name}: no driving lane outside junctions to "
                            "drive a trip on")
    trips = []
    while len(trips) < n_trips:
        poly, detour = _choose_route(road_map, pool, rng, min_route_m, max_route_m, detour_prob)
        truth = _drive(road_map, poly, rng, speed_mps, wobble_m)
        truth_yaw = _yaw_along(truth)
        hf = float(rng.uniform(*tall_factor)) if rng.random() < tall_prob else 1.0
        T = float(truth.t[-1])
        k = int(rng.integers(n_observers[0], n_observers[1] + 1))
        observers, sightings, wrong = [], [], 0
        for j in range(k):
            tm = T * (0.05 + 0.9 * (j + rng.uniform()) / k)
            kind = OBSERVER_KINDS[int(rng.choice(3, p=np.asarray(kind_probs)))]
            obs = _observer(road_map, truth, truth_yaw, tm, kind, 100 + j, rng)
            if obs is None or len(obs.t) == 0:
                continue
            observers.append(obs)
            got, w = _sightings(road_map, truth, truth_yaw, obs, rng, height_factor=hf,
                                range_m=range_m, fov_deg=fov_deg,
                                wrong_side_prob=wrong_side_prob)
            sightings.extend(got)
            wrong += w
        if len(sightings) < min_sightings:
            continue
        sightings.sort(key=lambda s: (s.t, s.observer_id))
        trips.append(SynthTrip(len(trips), truth, tuple(sightings), tuple(observers), detour,
                               hf, wrong))
    return trips


def run_bench(road_map: RoadMap, trips: int | Sequence[SynthTrip], seed: int = 0,
              methods: Sequence[str] = ("shortest-path", "hmm")) -> dict:
    """Reconstruct synthetic trips with each method and score them (SSPD, Hausdorff).

    Each reconstruction is scored against the truth between its trip's first
    and last sighting (`SynthTrip.truth_window`), with `metrics.sspd` and
    `metrics.hausdorff` on the points as given (metres).

    Args:
        road_map: the map.
        trips: a number of trips to make with ``numpy.random.default_rng(seed)``,
            or trips already made.
        seed: the seed used when `trips` is a number.
        methods: names in `reconstruct.METHODS`.

    Returns:
        ``{"map", "trips", "seed", "methods": {name: {"sspd_mean_m",
        "sspd_median_m", "hausdorff_mean_m", "hausdorff_median_m",
        "time_mean_ms", "time_median_ms", "warnings"}}, "rows": [per trip and
        method: trip, method, sightings, sspd_m, hausdorff_m, time_ms, warnings]}``.

    Raises:
        ReconstructionError: an unknown method name (listing the valid ones).
    """
    from dashtraj.trajectory.metrics import hausdorff, sspd
    from dashtraj.trajectory.reconstruct import METHODS, ReconstructionError, reconstruct

    for m in methods:
        if m not in METHODS:
            raise ReconstructionError(
                f"unknown reconstruction method {m!r}; valid: {', '.join(sorted(METHODS))}")
    if isinstance(trips, int):
        trips = make_trips(road_map, trips, np.random.default_rng(seed))
    rows = []
    for trip in trips:
        truth = trip.truth_window()
        for m in methods:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                t0 = time.perf_counter()
                rec = reconstruct(road_map, list(trip.sightings), method=m)
                ms = (time.perf_counter() - t0) * 1e3
            rows.append({
                "trip": trip.trip_id, "method": m, "sightings": len(trip.sightings),
                "detour": trip.detour, "wrong_side": trip.wrong_side,
                "sspd_m": sspd(truth, rec.trajectory),
                "hausdorff_m": hausdorff(truth, rec.trajectory),
                "time_ms": ms, "warnings": len(caught),
            })
    summary = {}
    for m in methods:
        r = [row for row in rows if row["method"] == m]
        col = {k: np.array([row[k] for row in r]) for k in ("sspd_m", "hausdorff_m", "time_ms")}
        summary[m] = {
            "sspd_mean_m": float(col["sspd_m"].mean()),
            "sspd_median_m": float(np.median(col["sspd_m"])),
            "hausdorff_mean_m": float(col["hausdorff_m"].mean()),
            "hausdorff_median_m": float(np.median(col["hausdorff_m"])),
            "time_mean_ms": float(col["time_ms"].mean()),
            "time_median_ms": float(np.median(col["time_ms"])),
            "warnings": int(sum(row["warnings"] for row in r)),
        }
    return {"map": road_map.name, "trips": len(trips), "seed": seed, "methods": summary,
            "rows": rows}
