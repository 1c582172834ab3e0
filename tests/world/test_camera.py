"""Camera: intrinsics, a hand-computed projection, labels on constructed scenes."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from dashtraj.world.camera import (
    DETECTION_CLASSES,
    CameraSpec,
    camera_poses,
    orientation_of,
    project,
    visible_boxes,
    world_to_camera,
)

SPEC = CameraSpec()  # 1280 x 720, FOV 90, 1.0 m ahead, 1.6 m high


def test_intrinsics_match_carla():
    assert math.isclose(SPEC.focal_px, 640.0)  # 1280 / (2 tan 45°), the paper's 640 px
    assert np.allclose(SPEC.K, [[640, 0, 640], [0, 640, 360], [0, 0, 1]])


def test_known_point_lands_on_hand_computed_pixel():
    # 10 m ahead, 2 m right, 1 m below the camera: OpenCV (2, 1, 10)
    # u = 640 * 2 / 10 + 640 = 768, v = 640 * 1 / 10 + 360 = 424
    assert np.allclose(project(SPEC, [10.0, 2.0, -1.0]), [768.0, 424.0])
    # the same point in the world: observer at (5, 5) facing +y (yaw 90°): forward is +y,
    # right is -x in CARLA's left-handed frame
    cx, cy, cz, cyaw = camera_poses(SPEC, np.array([5.0]), np.array([5.0]), np.array([0.0]),
                                    np.array([90.0]))
    assert np.allclose([cx[0], cy[0], cz[0]], [5.0, 6.0, 1.6])
    world = [cx[0] - 2.0, cy[0] + 10.0, cz[0] - 1.0]
    p_cam = world_to_camera(world, [cx[0], cy[0], cz[0]], cyaw[0])
    assert np.allclose(p_cam, [10.0, 2.0, -1.0])
    assert np.allclose(project(SPEC, p_cam), [768.0, 424.0])


@given(st.floats(1.0, 80.0), st.floats(-40.0, 40.0), st.floats(-5.0, 5.0),
       st.floats(-180.0, 180.0), st.floats(-10.0, 10.0))
def test_projection_inverts_through_k(fwd, right, up, yaw, pitch):
    p = np.array([fwd, right, up])
    uv = project(CameraSpec(pitch_deg=pitch), p)
    ray = np.linalg.inv(SPEC.K) @ np.array([uv[0], uv[1], 1.0]) * fwd  # OpenCV
    assert np.allclose([ray[2], ray[0], -ray[1]], p, atol=1e-6)
    # world_to_camera is a rotation: it keeps distances
    cam = np.array([3.0, -2.0, 1.6])
    q = world_to_camera(cam + p, cam, yaw, pitch)
    assert math.isclose(np.linalg.norm(q), np.linalg.norm(p), rel_tol=1e-9)


def _scene(vx, vy, vyaw, length=4.5, width=1.9, height=1.5):
    n = len(vx)
    return visible_boxes(SPEC, np.array([0.0]), np.array([0.0]), np.array([0.0]),
                         np.array([0.0]), np.asarray(vx, float), np.asarray(vy, float),
                         np.zeros(n), np.asarray(vyaw, float), np.full(n, length),
                         np.full(n, width), np.full(n, height))


def test_orientation_labels_on_constructed_cases():
    # observer at the origin facing +x; camera at (1, 0, 1.6)
    g = _scene([20.0, 20.0, 20.0], [0.0, 3.5, -8.0], [180.0, 0.0, 90.0])
    labels = dict(zip(g["veh"].tolist(), g["orientation"].tolist(), strict=True))
    assert labels == {0: "front", 1: "back", 2: "side"}  # oncoming, driving away, crossing


def test_orientation_thresholds():
    assert orientation_of([0, 44.9, -44.9, 45.1, 134.9, 135.1, -179, 180]).tolist() == [
        "back", "back", "back", "side", "side", "front", "front", "front"]


def test_distance_and_signed_bearing():
    g = _scene([11.0, 11.0], [10.0, -10.0], [0.0, 0.0])
    assert np.allclose(g["distance_m"], math.hypot(10, 10))
    assert np.allclose(sorted(g["bearing_deg"]), [-45.0, 45.0])
    right = g["veh"] == 0  # +y is right of a camera facing +x
    assert g["bearing_deg"][right][0] > 0


def test_box_clipping_truncation_and_culling():
    # far left: partly out of the image -> truncated; behind: dropped; far away: dropped
    g = _scene([6.0, -10.0, 100.0, 20.0], [-6.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0])
    assert sorted(g["veh"].tolist()) == [0, 3]
    trunc = dict(zip(g["veh"].tolist(), g["truncation"].tolist(), strict=True))
    assert 0.0 < trunc[0] < 1.0 and trunc[3] == 0.0
    assert (g["u_min"] >= 0).all() and (g["u_max"] <= 1280).all()
    assert (g["v_min"] >= 0).all() and (g["v_max"] <= 720).all()
    centre = g["veh"] == 3
    # centred car 20 m ahead of the origin: its box is centred horizontally
    assert math.isclose(g["u_min"][centre][0] + g["u_max"][centre][0], 1280.0, rel_tol=1e-9)


def test_observer_does_not_see_itself():
    g = visible_boxes(SPEC, np.array([0.0]), np.array([0.0]), np.array([0.0]), np.array([0.0]),
                      np.array([0.0, 15.0]), np.array([0.0, 0.0]), np.zeros(2), np.zeros(2),
                      np.full(2, 4.5), np.full(2, 1.9), np.full(2, 1.5), obs_index=np.array([0]))
    assert g["veh"].tolist() == [1]


def test_detection_classes_order():
    assert len(DETECTION_CLASSES) == 15
    assert DETECTION_CLASSES[:3] == ("car_front", "car_back", "car_side")
    assert DETECTION_CLASSES[-1] == "bicycle_side"
