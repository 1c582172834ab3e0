"""The dashcam model and ground-truth labels of what each camera sees.

A pinhole camera like CARLA's ideal `sensor.camera.rgb`: image W x H pixels,
horizontal field of view FOV, focal length f = W / (2 tan(FOV/2)) pixels for both
axes, principal point at the image centre. The camera is fixed to its vehicle at
(x_m forward, y_m right, z_m up) from the vehicle's ground point (centre of the box
at road level), pitched by `pitch_deg` (positive looks up).

Frames:
- vehicle / camera axes: x forward, y right, z up (CARLA's, left-handed);
- OpenCV camera axes: x right, y down, z forward; a camera-axes vector (x, y, z)
  is (y, -z, x) in OpenCV axes;
- image: u to the right, v down, pixels, origin at the top-left corner.

Ground truth per observer and frame, for every other vehicle whose centre is
within `max_range_m` and whose box projects into the image (see `visible_boxes`):

- the 3-D box (centre x, y, z; extents = half length, half width, half height;
  yaw), CARLA world, metres and degrees;
- the 2-D box: the 8 box corners in front of the camera (depth > `near_m`) are
  projected and their bounding rectangle is clipped to the image; dropped when
  it lies fully outside or when no corner is in front;
- truncation in [0, 1]: the share of the unclipped rectangle's area outside the
  image, raised to the share of corners behind the camera when that is larger;
- distance_m: ground-plane distance from the camera to the box centre, metres;
- bearing_deg: signed horizontal angle of the box centre off the camera axis,
  degrees, positive to the right (the sign the paper's Eq. 8 loses);
- orientation, from rel = heading of the seen vehicle − direction of the ray
  from the camera to it, wrapped to [−180°, 180°): ``back`` if |rel| < 45° (it
  drives away from us: we see its rear), ``front`` if |rel| > 135° (it faces us),
  ``side`` otherwise;
- label: f"{vehicle_class}_{orientation}", one of `DETECTION_CLASSES`.

Occlusion by other vehicles or buildings is not computed here; the renderer, which
draws the scene, decides what is hidden.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

MIN_IMAGE_SIDE_PX = 8
MAX_IMAGE_SIDE_PX = 8192
"""Image sides dashtraj renders and reads, pixels (llvmpipe and most GPUs allow 8192+)."""

DETECTION_CLASSES: tuple[str, ...] = (
    "car_front", "car_back", "car_side",
    "truck_front", "truck_back", "truck_side",
    "bus_front", "bus_back", "bus_side",
    "motorcycle_front", "motorcycle_back", "motorcycle_side",
    "bicycle_front", "bicycle_back", "bicycle_side",
)
"""The 15 classes of the vehicle orientation dataset, in its order (class index = position)."""


@dataclass(frozen=True, slots=True)
class CameraSpec:
    """A dashcam: image size (pixels), horizontal FOV (degrees), mount (metres, degrees).

    The mount (x_m forward, y_m right, z_m up) is relative to the vehicle's ground
    point (box centre at road level); `pitch_deg` > 0 looks up. The defaults are the
    paper's (1280 x 720, FOV 90°), mounted 1.0 m ahead of the centre, 1.6 m high.
    """

    width_px: int = 1280
    height_px: int = 720
    fov_deg: float = 90.0
    x_m: float = 1.0
    y_m: float = 0.0
    z_m: float = 1.6
    pitch_deg: float = 0.0

    @property
    def focal_px(self) -> float:
        """f = W / (2 tan(FOV/2)), pixels (the paper's Eq. 4)."""
        return self.width_px / (2.0 * math.tan(math.radians(self.fov_deg) / 2.0))

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix (Eq. 5): [[f, 0, W/2], [0, f, H/2], [0, 0, 1]]."""
        f = self.focal_px
        return np.array([[f, 0.0, self.width_px / 2.0], [0.0, f, self.height_px / 2.0],
                         [0.0, 0.0, 1.0]])

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> CameraSpec:
        return cls(**d)


def camera_poses(spec: CameraSpec, x, y, z, yaw_deg):
    """Camera positions and yaws for vehicles at ground points (x, y, z) with yaw.

    Args:
        x, y, z, yaw_deg: (N,) vehicle ground points (CARLA world, metres) and yaws (deg).

    Returns:
        cx, cy, cz (N,) camera centres, CARLA world, metres; cyaw (N,) degrees.
    """
    h = np.radians(np.asarray(yaw_deg, dtype=float))
    c, s = np.cos(h), np.sin(h)
    cx = np.asarray(x) + spec.x_m * c - spec.y_m * s
    cy = np.asarray(y) + spec.x_m * s + spec.y_m * c
    return cx, cy, np.asarray(z) + spec.z_m, np.asarray(yaw_deg, dtype=float)


def world_to_camera(points, cam_xyz, cam_yaw_deg: float, pitch_deg: float = 0.0) -> np.ndarray:
    """World points into camera axes (x forward, y right, z up), metres.

    Args:
        points: (..., 3) CARLA world, metres.
        cam_xyz: (3,) camera centre; cam_yaw_deg, pitch_deg: its orientation.
    """
    d = np.asarray(points, dtype=float) - np.asarray(cam_xyz, dtype=float)
    h, p = math.radians(cam_yaw_deg), math.radians(pitch_deg)
    ch, sh = math.cos(h), math.sin(h)
    fwd_h = d[..., 0] * ch + d[..., 1] * sh          # along the heading, ground plane
    right = -d[..., 0] * sh + d[..., 1] * ch         # right of it (left-handed frame)
    up = d[..., 2]
    cp, sp = math.cos(p), math.sin(p)
    return np.stack([fwd_h * cp + up * sp, right, -fwd_h * sp + up * cp], axis=-1)


def project(spec: CameraSpec, p_cam) -> np.ndarray:
    """Pinhole projection of camera-axes points (..., 3) to pixels (..., 2) (u, v).

    Camera axes (x fwd, y right, z up) become OpenCV's (y, −z, x); u = f X/Z + W/2,
    v = f Y/Z + H/2. Points must be in front (x > 0); others give meaningless pixels.
    """
    p = np.asarray(p_cam, dtype=float)
    f = spec.focal_px
    depth = p[..., 0]
    u = f * p[..., 1] / depth + spec.width_px / 2.0
    v = f * (-p[..., 2]) / depth + spec.height_px / 2.0
    return np.stack([u, v], axis=-1)


def orientation_of(rel_deg) -> np.ndarray:
    """Orientation label from rel = seen heading − camera-to-vehicle ray direction (deg).

    |rel| < 45 → "back", |rel| > 135 → "front", else "side" (see the module docstring).
    """
    a = np.abs((np.asarray(rel_deg, dtype=float) + 180.0) % 360.0 - 180.0)
    return np.where(a < 45.0, "back", np.where(a > 135.0, "front", "side"))


def box_corners(cx, cy, z_ground, yaw_deg, length, width, height) -> np.ndarray:
    """The 8 corners (N, 8, 3) of boxes standing on the road, CARLA world, metres."""
    h = np.radians(np.asarray(yaw_deg, dtype=float))
    c, s = np.cos(h), np.sin(h)
    sx = np.array([1, 1, -1, -1, 1, 1, -1, -1], dtype=float) * 0.5
    sy = np.array([1, -1, -1, 1, 1, -1, -1, 1], dtype=float) * 0.5
    sz = np.array([0, 0, 0, 0, 1, 1, 1, 1], dtype=float)
    lx = np.asarray(length)[:, None] * sx
    ly = np.asarray(width)[:, None] * sy
    x = np.asarray(cx)[:, None] + lx * c[:, None] - ly * s[:, None]
    y = np.asarray(cy)[:, None] + lx * s[:, None] + ly * c[:, None]
    z = np.asarray(z_ground)[:, None] + np.asarray(height)[:, None] * sz
    return np.stack([x, y, z], axis=-1)


def visible_boxes(spec: CameraSpec, obs_x, obs_y, obs_z, obs_yaw, veh_x, veh_y, veh_z, veh_yaw,
                  length, width, height, obs_index=None, max_range_m: float = 60.0,
                  near_m: float = 0.1):
    """Ground-truth boxes every observer's camera sees (occlusion ignored).

    Args:
        obs_*: (M,) observer ground points (metres) and yaws (deg), CARLA world.
        veh_*: (N,) every vehicle's ground point and yaw; length, width, height (N,) m.
        obs_index: (M,) int, each observer's own index among the vehicles (never
            reported as seen by itself), or None when observers are not among them.
        max_range_m: ground-plane camera-to-centre distance limit, metres.
        near_m: corners with depth <= near_m (metres) count as behind the camera.

    Returns:
        dict of equal-length arrays, one row per (observer index m, vehicle index n)
        seen: "obs" and "veh" (int indices into the inputs), "cam_x", "cam_y",
        "cam_z", "cam_yaw", "cx", "cy", "cz" (box centre), "u_min", "v_min",
        "u_max", "v_max" (pixels, clipped), "truncation", "distance_m",
        "bearing_deg", "orientation".
    """
    cam_x, cam_y, cam_z, cam_yaw = camera_poses(spec, obs_x, obs_y, obs_z, obs_yaw)
    veh_x, veh_y = np.asarray(veh_x, float), np.asarray(veh_y, float)
    dx = veh_x[None, :] - cam_x[:, None]
    dy = veh_y[None, :] - cam_y[:, None]
    dist = np.hypot(dx, dy)
    near = dist <= max_range_m
    if obs_index is not None:
        oi = np.asarray(obs_index)
        ok = oi >= 0
        near[np.flatnonzero(ok), oi[ok]] = False
    mi, ni = np.nonzero(near)
    out = {k: np.zeros(0) for k in ("cam_x", "cam_y", "cam_z", "cam_yaw", "cx", "cy", "cz",
                                    "u_min", "v_min", "u_max", "v_max", "truncation",
                                    "distance_m", "bearing_deg")}
    out["obs"] = mi
    out["veh"] = ni
    out["orientation"] = np.zeros(0, dtype="<U5")
    if len(mi) == 0:
        return out
    corners = box_corners(veh_x[ni], veh_y[ni], np.asarray(veh_z)[ni], np.asarray(veh_yaw)[ni],
                          np.asarray(length)[ni], np.asarray(width)[ni], np.asarray(height)[ni])
    h = np.radians(cam_yaw[mi])
    p = np.radians(spec.pitch_deg)
    d = corners - np.stack([cam_x[mi], cam_y[mi], cam_z[mi]], -1)[:, None, :]
    ch, sh = np.cos(h)[:, None], np.sin(h)[:, None]
    fwd_h = d[..., 0] * ch + d[..., 1] * sh
    right = -d[..., 0] * sh + d[..., 1] * ch
    up = d[..., 2]
    fwd = fwd_h * math.cos(p) + up * math.sin(p)
    upc = -fwd_h * math.sin(p) + up * math.cos(p)
    front = fwd > near_m
    f = spec.focal_px
    safe = np.where(front, fwd, 1.0)
    u = f * right / safe + spec.width_px / 2.0
    v = f * (-upc) / safe + spec.height_px / 2.0
    big = np.inf
    u0 = np.where(front, u, big).min(1)
    u1 = np.where(front, u, -big).max(1)
    v0 = np.where(front, v, big).min(1)
    v1 = np.where(front, v, -big).max(1)
    any_front = front.any(1)
    W, H = float(spec.width_px), float(spec.height_px)
    cu0, cu1 = np.clip(u0, 0, W), np.clip(u1, 0, W)
    cv0, cv1 = np.clip(v0, 0, H), np.clip(v1, 0, H)
    inside = any_front & (cu1 > cu0) & (cv1 > cv0)
    with np.errstate(invalid="ignore", divide="ignore"):
        area = (u1 - u0) * (v1 - v0)
        trunc = 1.0 - (cu1 - cu0) * (cv1 - cv0) / np.where(area > 0, area, 1.0)
    trunc = np.maximum(np.where(area > 0, trunc, 1.0), 1.0 - front.mean(1))
    keep = inside
    # centre, bearing, orientation
    cx, cy = veh_x[ni], veh_y[ni]
    cz = np.asarray(veh_z)[ni] + 0.5 * np.asarray(height)[ni]
    ray = np.degrees(np.arctan2(dy[mi, ni], dx[mi, ni]))
    bearing = (ray - cam_yaw[mi] + 180.0) % 360.0 - 180.0
    rel = np.asarray(veh_yaw, float)[ni] - ray
    res = {
        "obs": mi, "veh": ni, "cam_x": cam_x[mi], "cam_y": cam_y[mi], "cam_z": cam_z[mi],
        "cam_yaw": cam_yaw[mi], "cx": cx, "cy": cy, "cz": cz,
        "u_min": cu0, "v_min": cv0, "u_max": cu1, "v_max": cv1,
        "truncation": np.clip(trunc, 0.0, 1.0), "distance_m": dist[mi, ni],
        "bearing_deg": bearing, "orientation": orientation_of(rel),
    }
    return {k: val[keep] for k, val in res.items()}
