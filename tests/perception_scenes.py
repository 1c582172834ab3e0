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
