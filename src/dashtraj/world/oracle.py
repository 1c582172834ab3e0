"""Oracle sightings: what a perfect detector + tracker would report, from a recording's
ground truth, with optional localization noise like the paper's.

Protocol (`oracle_sightings`):

1. Keep the truth rows of one vehicle (the target by default) seen within
   `max_distance_m` of a camera (15 m: the paper's ReID range).
2. Per observer, split them into track segments where consecutive frames are more
   than `segment_gap_s` apart; each segment gets a track id (numbered 1, 2, ... in
   order of (observer, start time)).
3. Keep one frame per segment every `sample_s` seconds (the first frame of each
   `sample_s` bin from the segment's start).
4. Estimate the position from the camera (``observer_x``, ``observer_y`` of the
   sighting are the camera centre, ``observer_yaw`` its heading):

       x = cam_x + D cos(cam_yaw + bearing),  y = cam_y + D sin(cam_yaw + bearing)

   with the signed bearing and the observer's yaw added — the paper's Eq. 8 loses
   the sign and its Eq. 9 forgets the yaw (see DESIGN.md); dashtraj does not.

Noise models (`NOISE_MODELS`):

- ``none``: the true ground-plane distance and bearing; positions are exact.
- ``paper``: the photogrammetric distance of Eq. 3 assumes a class height
  (`ASSUMED_HEIGHT_M`: 1.6 m car, 3.5 m truck/bus, 1.45 m motorcycle/bicycle). An
  image height h_px ∝ H_real / D, so Eq. 3 returns D · H_assumed / H_real for a
  vehicle whose real (catalog) height is H_real; on top of that, Gaussian errors
  of σ = `distance_sigma_m` (distance; with the height bias the RMSE under 20 m is
  about the paper's 2.3 m) and `bearing_sigma_deg` (bearing, 2°), and with
  probability `wrong_side_prob` the bearing's sign is flipped (the estimate lands
  mirrored across the camera axis, on the wrong side of the road).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from dashtraj.errors import DashtrajError
from dashtraj.trajectory.records import Sighting

NOISE_MODELS: tuple[str, ...] = ("none", "paper")

ASSUMED_HEIGHT_M: dict[str, float] = {
    "car": 1.6, "truck": 3.5, "bus": 3.5, "motorcycle": 1.45, "bicycle": 1.45,
}
"""Eq. 3's per-class real heights, metres (the paper's; buses counted as trucks)."""


class OracleError(DashtrajError, ValueError):
    """Bad oracle settings (unknown noise model, unknown vehicle)."""


@dataclass(frozen=True, slots=True)
class OracleConfig:
    """Settings of `oracle_sightings`; distances in metres, angles in degrees, times s.

    `vehicle` is a vehicle id or "target".
    """

    vehicle: int | str = "target"
    max_distance_m: float = 15.0
    sample_s: float = 0.5
    segment_gap_s: float = 1.0
    noise: str = "none"
    seed: int = 0
    distance_sigma_m: float = 1.5
    bearing_sigma_deg: float = 2.0
    wrong_side_prob: float = 0.03

    def to_dict(self) -> dict:
        return asdict(self)


def oracle_sightings(recording, config: OracleConfig = OracleConfig()) -> list[Sighting]:
    """Sightings of one vehicle from a recording's truth (protocol in the module docstring).

    Args:
        recording: a `dashtraj.world.recording.Recording`.
        config: the settings; its seed makes the noise reproducible.

    Returns:
        Sightings sorted by (t, observer_id).

    Raises:
        OracleError: unknown noise model or vehicle id.
    """
    if config.noise not in NOISE_MODELS:
        raise OracleError(f"unknown noise model {config.noise!r}; valid: "
                          f"{', '.join(NOISE_MODELS)}")
    if config.vehicle == "target":
        vid = int(recording.meta.get("target_vehicle_id", 0))
    else:
        try:
            vid = int(config.vehicle)
        except ValueError as exc:
            raise OracleError(f"vehicle must be an id or 'target', got {config.vehicle!r}") from exc
    veh = recording.vehicle(vid)
    vclass = veh["vehicle_class"]
    truth = recording.truth
    cols = {c: truth.column(c).to_numpy(zero_copy_only=False)
            for c in ("t", "observer_id", "vehicle_id", "cam_x", "cam_y", "cam_yaw",
                      "distance_m", "bearing_deg", "orientation")}
    sel = (cols["vehicle_id"] == vid) & (cols["distance_m"] <= config.max_distance_m)
    c = {k: v[sel] for k, v in cols.items()}
    order = np.lexsort((c["t"], c["observer_id"]))
    c = {k: v[order] for k, v in c.items()}
    n = len(c["t"])
    if n == 0:
        return []
    obs, t = c["observer_id"], c["t"]
    new_seg = np.ones(n, dtype=bool)
    new_seg[1:] = (obs[1:] != obs[:-1]) | (np.diff(t) > config.segment_gap_s)
    seg = np.cumsum(new_seg)  # track ids 1, 2, ...
    t0 = t[new_seg][seg - 1]
    b = np.floor((t - t0) / config.sample_s + 1e-9).astype(np.int64)
    keep = np.ones(n, dtype=bool)
    keep[1:] = (seg[1:] != seg[:-1]) | (b[1:] != b[:-1])
    c = {k: v[keep] for k, v in c.items()}
    seg = seg[keep]
    d, bearing = c["distance_m"].astype(float), c["bearing_deg"].astype(float)
    if config.noise == "paper":
        rng = np.random.default_rng(config.seed)
        m = len(d)
        # Eq. 3: photogrammetric distance with the class's assumed height
        d = d * ASSUMED_HEIGHT_M[vclass] / float(veh["height_m"])
        d = np.maximum(d + rng.normal(0.0, config.distance_sigma_m, m), 0.5)
        bearing = bearing + rng.normal(0.0, config.bearing_sigma_deg, m)
        flip = rng.random(m) < config.wrong_side_prob
        bearing = np.where(flip, -bearing, bearing)
    ang = np.radians(c["cam_yaw"] + bearing)  # observer yaw + signed bearing (not Eq. 8/9)
    x = c["cam_x"] + d * np.cos(ang)
    y = c["cam_y"] + d * np.sin(ang)
    out = [
        Sighting(t=float(c["t"][i]), observer_id=int(c["observer_id"][i]),
                 observer_x=float(c["cam_x"][i]), observer_y=float(c["cam_y"][i]),
                 observer_yaw=float(c["cam_yaw"][i]), x=float(x[i]), y=float(y[i]),
                 orientation=str(c["orientation"][i]), vehicle_class=vclass,
                 track_id=int(seg[i]), distance=float(d[i]), bearing=float(bearing[i]))
        for i in range(len(d))
    ]
    out.sort(key=lambda s: (s.t, s.observer_id))
    return out
