"""Scripted scenes for the perception tests: hand-made poses drawn by the real renderer.

A scene is a list of frames; each frame has the observer's camera pose (CARLA world)
and the states (vehicle id, x, y, yaw) of the other vehicles. `render_scene` draws
them with `dashtraj.render.scene.Renderer` on a flat straight road and returns frames
shaped like `RecordingFrame` (``frame_data`` with labels, ``vehicle_ids``), so the
oracle detector and the trackers take them as they take a recording's frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from dashtraj.perception.localize import CameraPose
from dashtraj.roads import RoadMap
from dashtraj.world.camera import CameraSpec
from render_scene import STRAIGHT_XODR

CAM_HEIGHT_M = 1.6


@dataclass(frozen=True)
class SceneFrame:
    t: float
    frame: int
    frame_data: object
    vehicle_ids: tuple[int, ...]
    pose: CameraPose


def car_identities():
    """Three catalog cars of different looks (vehicle ids 1, 2, 3 → identities)."""
    from dashtraj.world import catalog

    cars = [i for i in catalog.identities() if i.model.vehicle_class == "car"]
    return {1: cars[0], 2: cars[7], 3: cars[15], 4: cars[22]}


def render_scene(frames, spec: CameraSpec, identities=None):
    """Render scripted frames: each (t, (cam_x, cam_y, cam_yaw), [(vid, x, y, yaw), ...])."""
    from dashtraj.render.scene import Renderer

    ids = identities or car_identities()
    r = Renderer(RoadMap.from_string(STRAIGHT_XODR, name="straight"), spec.width_px,
                 spec.height_px, spec.fov_deg, msaa=0)
    out = []
    try:
        for k, (t, (cx, cy, cyaw), vehicles) in enumerate(frames):
            pose = (cx, cy, CAM_HEIGHT_M, cyaw, 0.0, 0.0)
            vs = [(vid, ids[vid], x, y, 0.0, yaw) for vid, x, y, yaw in vehicles]
            f = r.render(pose, vs, labels=True, depth=False)
            out.append(SceneFrame(t, k, f, tuple(v[0] for v in vs),
                                  CameraPose(cx, cy, CAM_HEIGHT_M, cyaw, 0.0, 0.0)))
    finally:
        r.release()
    return out


def straight(x0, y0, yaw_deg, speed_mps, t):
    h = math.radians(yaw_deg)
    return x0 + speed_mps * t * math.cos(h), y0 + speed_mps * t * math.sin(h), yaw_deg


def pass_scene(duration_s: float = 6.0, hz: float = 10.0):
    """The observer drives +x at 8 m/s; car 1 overtakes it on the left (14 m/s), car 2
    comes the other way (10 m/s), car 3 crosses the road from the right 60 m ahead
    of the start (12 m/s)."""
    frames = []
    for k in range(round(duration_s * hz) + 1):
        t = k / hz
        cam = straight(-60.0, 1.75, 0.0, 8.0, t)
        frames.append((t, cam, [
            (1, *straight(-76.0, -1.75, 0.0, 14.0, t)),
            (2, *straight(-20.0, -5.25, 180.0, 10.0, t)),
            (3, *straight(0.0, 22.0, -90.0, 12.0, t)),
        ]))
    return frames


def turn_scene(hz: float = 10.0, speed_mps: float = 5.0, yaw_rate_dps: float = 45.0):
    """The observer drives 0.5 s along +x in the outer right lane, then turns 90° left
    across the road (yaw → −90°) at `yaw_rate_dps` on an arc, then drives on along −y;
    cars 1–3 wait on the road ahead and sweep across the image during the turn."""
    t_turn = 90.0 / yaw_rate_dps
    radius = speed_mps / math.radians(yaw_rate_dps)
    x0, y0 = -30.0 + 0.5 * speed_mps, 5.25
    frames = []
    for k in range(round((1.0 + t_turn) * hz) + 1):
        t = k / hz
        if t <= 0.5:
            cam = straight(-30.0, y0, 0.0, speed_mps, t)
        elif t <= 0.5 + t_turn:
            th = math.radians(yaw_rate_dps * (t - 0.5))
            cam = (x0 + radius * math.sin(th), y0 - radius * (1 - math.cos(th)),
                   -math.degrees(th))
        else:
            cam = straight(x0 + radius, y0 - radius, -90.0, speed_mps, t - 0.5 - t_turn)
        frames.append((t, cam, [(1, -8.0, -5.25, 180.0), (2, -2.0, 1.75, 0.0),
                                (3, 6.0, -1.75, 0.0)]))
    return frames


def look_away_scene(hz: float = 10.0, speed_mps: float = 5.0, away_s: float = 4.0):
    """The observer drives +x at `speed_mps` behind car 1 (15 m ahead, same speed) and
    turns its camera 80° to the left and back (1 s each way), the car out of view for
    about `away_s` + 1 s in between, as a driver's head or a turning car would."""
    frames = []
    n = round((1.0 + 1.0 + away_s + 1.0 + 1.5) * hz) + 1
    for k in range(n):
        t = k / hz
        if t <= 1.0:
            yaw = 0.0
        elif t <= 2.0:
            yaw = -80.0 * (t - 1.0)
        elif t <= 2.0 + away_s:
            yaw = -80.0
        elif t <= 3.0 + away_s:
            yaw = -80.0 * (3.0 + away_s - t)
        else:
            yaw = 0.0
        x, y, _ = straight(-60.0, 1.75, 0.0, speed_mps, t)
        frames.append((t, (x, y, yaw), [(1, *straight(-45.0, 1.75, 0.0, speed_mps, t))]))
    return frames


def look_away_two_scene(hz: float = 10.0, speed_mps: float = 5.0, away_s: float = 4.0,
                        swap: bool = False):
    """`look_away_scene` with two cars ahead, car 1 in the observer's lane 15 m ahead and
    car 2 in the lane to its left 24 m ahead, both at its speed. ``swap``: while the
    camera looks away car 1 becomes car 3 (another look) and car 2 car 4: the cars seen
    after the glance are not the ones seen before, where those would be."""
    out = []
    for t, cam, _ in look_away_scene(hz, speed_mps, away_s):
        later = swap and t > 2.0 + away_s / 2
        out.append((t, cam, [(3 if later else 1, *straight(-45.0, 1.75, 0.0, speed_mps, t)),
                             (4 if later else 2, *straight(-36.0, -1.75, 0.0, speed_mps, t))]))
    return out
