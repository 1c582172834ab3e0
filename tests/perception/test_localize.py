"""Localizers on the renderer: each estimator's error at 10 m within a stated bound, the
calibration of Eq. 3's constant, and the signed bearing with the observer's yaw."""

from __future__ import annotations

import numpy as np
import pytest

from dashtraj.perception.detections import OracleDetector
from dashtraj.perception.localize import (
    CameraPose,
    LocalizationError,
    build_localizer,
    calibrate_paper_constant,
    place,
)
from dashtraj.world.camera import CameraSpec
from perception_scenes import render_scene

SPEC = CameraSpec()  # 1280 x 720, FOV 90°, the paper's camera
BEARINGS = (-30.0, -15.0, 0.0, 15.0, 30.0)


@pytest.fixture(scope="module")
def at_10m(gl_available):
    """One catalog car at 10 m ground distance from the camera, at five bearings and three
    headings (away, towards, across), the camera at (-50, 0) looking along +x (yaw 0)."""
    frames, truth = [], []
    for b in BEARINGS:
        for yaw in (0.0, 180.0, 90.0):
            x = -50.0 + 10.0 * np.cos(np.radians(b))
            y = 10.0 * np.sin(np.radians(b))
            frames.append((0.0, (-50.0, 0.0, 0.0), [(1, x, y, yaw)]))
            truth.append((x, y))
    rendered = render_scene(frames, SPEC)
    dets = [OracleDetector().detect(f) for f in rendered]
    assert all(len(d) == 1 for d in dets)
    return rendered, dets, np.array(truth)


# Bounds at 10 m on the 1280 x 720 camera (measured: paper 0.20–1.69 m with our calibrated
# constant, the car's real height is not Eq. 3's 1.6 m and Eq. 3 measures depth, not
# distance; ground 0.16–0.41 m; fused 0.20–0.41 m).
@pytest.mark.parametrize("name, bound_m", [("paper", 2.0), ("ground", 0.5), ("fused", 0.5)])
def test_error_at_10m_within_bound(at_10m, name, bound_m):
    rendered, dets, truth = at_10m
    loc = build_localizer(name)
    err = []
    for f, d, (tx, ty) in zip(rendered, dets, truth, strict=True):
        r = loc.localize(d.boxes, d.class_ids, SPEC, f.pose)
        err.append(np.hypot(r.x[0] - tx, r.y[0] - ty))
        # the bearing is signed: positive to the right (+y at yaw 0)
        true_b = np.degrees(np.arctan2(ty, tx + 50.0))
        assert abs(r.bearing_deg[0] - true_b) < 3.0  # box centre vs vehicle centre
    assert max(err) < bound_m, f"{name}: errors {np.round(err, 2)}"


def test_observer_yaw_is_added_to_the_signed_bearing():
    pose = CameraPose(10.0, 20.0, 1.6, 90.0)
    x, y = place(pose, np.array([10.0, 10.0]), np.array([30.0, -30.0]))
    # facing +y; 30° to the right turns toward −x in CARLA's left-handed frame
    assert np.allclose(x, [10.0 - 5.0, 10.0 + 5.0])
    assert np.allclose(y, [20.0 + 10.0 * np.cos(np.radians(30.0))] * 2)


def test_calibration_recovers_the_constant_of_an_ideal_camera():
    # an ideal box of a car exactly 1.6 m high at D: h_px = f 1.6 / D, so μ_h = I_H
    d = np.array([5.0, 12.0, 30.0, 51.0])
    h = SPEC.focal_px * 1.6 / d
    boxes = np.column_stack([np.full(4, 600.0), 360 - h / 2, np.full(4, 680.0), 360 + h / 2])
    mu = calibrate_paper_constant(SPEC, boxes, np.zeros(4, int), d)
    assert mu == pytest.approx(720.0)
    out = build_localizer("paper", mu_h=mu).localize(boxes, np.zeros(4, int), SPEC,
                                                     CameraPose(0, 0, 1.6, 0))
    assert np.allclose(out.distance_m, d)
    with pytest.raises(LocalizationError, match="positive"):
        calibrate_paper_constant(SPEC, boxes, np.zeros(4, int), -d)


@pytest.fixture(scope="module")
def near_model3(gl_available):
    """A Tesla Model 3 (4.69 m long, the catalog's mean car length 4.76 m) straight ahead
    at 5, 6 and 8 m ground distance, driving away and towards the camera (nearer, its
    lower edge leaves the image)."""
    from dashtraj.world import catalog
    from perception_scenes import car_identities

    cars = [i for i in catalog.identities() if i.model.vehicle_class == "car"]
    model3 = next(i for i in cars if i.model.blueprint_id == "vehicle.tesla.model3")
    frames, truth = [], []
    for dist in (5.0, 6.0, 8.0):
        for yaw in (0.0, 180.0):
            frames.append((0.0, (-50.0, 0.0, 0.0), [(1, -50.0 + dist, 0.0, yaw)]))
            truth.append(dist)
    ids = car_identities() | {1: model3}
    rendered = render_scene(frames, SPEC, ids)
    return rendered, np.array(truth)


def test_ground_near_range_uses_the_body_edge_not_the_wheels(near_model3):
    """Nearer than ~11 m the lowest pixel of a car is its body's lower edge (ground
    clearance above the road, half a length from the centre), not its wheel contact:
    measured errors +0.19 to +0.21 m on the CARLA-like meshes, whose rounded bumpers end
    above and inside the box corner (0.00-0.04 m on the earlier box-shaped ones; the
    wheel-contact model alone put the car 0.37-0.67 m too near)."""
    rendered, truth = near_model3
    loc = build_localizer("ground")
    err = []
    for f, dist in zip(rendered, truth, strict=True):
        d = OracleDetector().detect(f)
        r = loc.localize(d.boxes, d.class_ids, SPEC, f.pose)
        err.append(r.distance_m[0] - dist)
    assert max(abs(e) for e in err) < 0.3, np.round(err, 2)
