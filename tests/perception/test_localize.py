"""Localizers on the renderer: each estimator's error at 10 m within a stated bound, the
calibration of Eq. 3's constant, and the signed bearing with the observer's yaw."""

from __future__ import annotations

import numpy as np
import pytest

from dashtraj.perception.detections import DETECTION_CLASSES, OracleDetector
from dashtraj.perception.localize import (
    HIDDEN_SIGMA_REL,
    CameraPose,
    LocalizationError,
    build_localizer,
    calibrate_paper_constant,
    place,
)
from dashtraj.world.camera import CameraSpec
from perception_scenes import car_identities, render_scene

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


def test_box_evidence_flags_truncation_and_occlusion():
    from dashtraj.perception.localize import (
        CUT_BOTTOM,
        CUT_LEFT,
        CUT_RIGHT,
        HIDDEN_BOTTOM,
        HIDDEN_SIDE,
        box_evidence,
    )

    boxes = np.array([
        [0.0, 300.0, 80.0, 400.0],       # cut by the left border
        [1200.0, 500.0, 1280.0, 720.0],  # cut by the right and bottom borders
        [600.0, 350.0, 700.0, 400.0],    # far car: bottom 400
        [650.0, 340.0, 760.0, 440.0],    # nearer (bottom 440): covers the far car's right part
        [100.0, 350.0, 160.0, 390.0],    # clean, alone
    ])
    ev = box_evidence(boxes, SPEC)
    assert ev[0] == CUT_LEFT
    assert ev[1] == CUT_RIGHT | CUT_BOTTOM
    assert ev[2] == HIDDEN_BOTTOM | HIDDEN_SIDE
    assert ev[3] == 0  # the nearer box is not hidden by the farther one
    assert ev[4] == 0



def test_a_box_below_that_is_estimated_farther_is_no_occluder():
    """A near car's box stays at its own distance when a detector's part box (its lower
    half, cut by the image bottom, estimated far away by its height) lies below it.

    The boxes are the shipped detector's on a car 5.4 m ahead (town10 seed 4, observer 3,
    frame 570: a car_back the model called truck_front, and a bus_side box on its lower
    part). Before an occluder had to be nearer by its own estimate too, the car's box
    counted as hidden and was put 1 m beyond the part box's Eq. 3 distance: 24 m. A nearer
    box with its own estimate nearer still hides the far box (the last lines)."""
    pose = CameraPose(0.0, 0.0, 1.6, 0.0)
    car = [465.0, 265.0, 910.0, 637.0]
    part = [467.0, 558.0, 926.0, 720.0]
    truck_front, bus_side, car_back = (DETECTION_CLASSES.index(c)
                                       for c in ("truck_front", "bus_side", "car_back"))
    loc = build_localizer("fused")
    alone = loc.localize(np.array([car]), np.array([truck_front]), SPEC, pose).distance_m[0]
    both = loc.localize(np.array([car, part]), np.array([truck_front, bus_side]), SPEC, pose)
    assert 4.0 < alone < 7.0
    assert both.distance_m[0] == pytest.approx(alone)
    assert both.distance_m[1] > 10.0  # the part box: Eq. 3 of a bus 162 px high
    far, near = [600.0, 350.0, 700.0, 400.0], [590.0, 360.0, 720.0, 460.0]
    out = loc.localize(np.array([far, near]), np.array([car_back, car_back]), SPEC, pose)
    lone = loc.localize(np.array([far]), np.array([car_back]), SPEC, pose)
    assert out.distance_m[1] < out.distance_m[0] < lone.distance_m[0]  # hidden: not its bottom
    # the rule's distance (12.7 m) carries the rule's error (30 %: 3.8 m), not the cues'
    # (alone, its bottom row read to a pixel: 1.0 m at 27.0 m); the nearer box keeps its σ
    assert lone.sigma_m[0] < 0.06 * lone.distance_m[0]
    assert out.sigma_m[0] == pytest.approx(HIDDEN_SIGMA_REL * out.distance_m[0])
    assert out.gate_sigma_m[0] == pytest.approx(lone.sigma_m[0])  # a tracker gates with it
    near_alone = loc.localize(np.array([near]), np.array([car_back]), SPEC, pose)
    assert out.sigma_m[1] == pytest.approx(near_alone.sigma_m[0])
    # the tracker that reports ids counts the box with the cues' σ; a smoother's filter
    # (rule_sigma) with the rule's: the variance along the ray of the track it starts
    from dashtraj.perception.detections import Detections
    from dashtraj.perception.track import EgoTracker

    det = Detections(np.array([far, near]), np.ones(2), np.array([car_back, car_back]),
                     np.full(2, -1))
    for rule_sigma, sigma in ((False, lone.sigma_m[0]), (True, out.sigma_m[0])):
        tr = EgoTracker(spec=SPEC, rule_sigma=rule_sigma)
        tr.update(det, 0.0, pose)
        u = np.array([np.cos(np.radians(out.bearing_deg[0])),
                      np.sin(np.radians(out.bearing_deg[0]))])  # the ray (yaw 0)
        assert u @ tr.position_cov[0] @ u == pytest.approx(sigma**2)


@pytest.fixture(scope="module")
def crossing_occluder(gl_available):
    """Car 1 drives 30 m ahead of the observer at its speed (6 m/s); car 2 crosses the road
    15 m ahead and hides car 1's lower part for about 0.8 s (t = 1.6–2.4 s)."""
    from perception_scenes import straight

    frames = []
    for k in range(41):
        t = k / 10
        frames.append((t, straight(-60.0, 0.0, 0.0, 6.0, t),
                       [(1, *straight(-30.0, 0.0, 0.0, 6.0, t)),
                        (2, -45.0 + 6.0 * t, -12.0 + 6.0 * t, 90.0)]))
    rendered = render_scene(frames, SPEC)
    truth = np.array([[f[2][0][1], f[2][0][2]] for f in frames])
    return rendered, truth


def test_tracked_keeps_the_position_through_an_occlusion(crossing_occluder):
    """Measured: while car 2 hides car 1's bottom edge, ``fused`` (box bottom and height
    of what is visible) drifts to 4.20 m off; ``tracked`` takes the track's ground-plane
    filter for these flagged boxes and stays within 2.44 m; on clean boxes both are the
    same (0.85 m: this mesh's box at 30 m)."""
    from dashtraj.perception.localize import LocalizationError

    rendered, truth = crossing_occluder
    fused, tracked = build_localizer("fused"), build_localizer("tracked")
    err_f, err_t, flagged = [], [], []
    for f, (tx, ty) in zip(rendered, truth, strict=True):
        d = OracleDetector().detect(f)
        a = fused.localize(d.boxes, d.class_ids, SPEC, f.pose)
        b = tracked.localize(d.boxes, d.class_ids, SPEC, f.pose, t=f.t)
        if 1 not in d.truth_ids:
            continue
        i = list(d.truth_ids).index(1)
        err_f.append(np.hypot(a.x[i] - tx, a.y[i] - ty))
        err_t.append(np.hypot(b.x[i] - tx, b.y[i] - ty))
        flagged.append(a.evidence[i] != 0)
    err_f, err_t, flagged = np.array(err_f), np.array(err_t), np.array(flagged)
    assert flagged.sum() >= 5 and (~flagged).sum() >= 20
    assert err_f[flagged].max() > 4.0
    assert err_t[flagged].max() < 2.6, np.round(err_t, 2)
    assert np.allclose(err_t[~flagged][:10], err_f[~flagged][:10])
    with pytest.raises(LocalizationError, match="time"):
        build_localizer("tracked").localize(d.boxes, d.class_ids, SPEC, f.pose)


def test_smoothed_carries_later_clean_boxes_back_to_a_track_born_occluded(crossing_occluder):
    """The same scene from t = 1.8 s: car 1's track is *born* with its bottom edge hidden
    by car 2 (its first box read 2.35 m off), so the forward filter has no clean history
    and ``tracked`` follows the flagged boxes (measured on the 5 flagged boxes: up to
    3.86 m off, RMS 2.90 m; ``fused`` 4.20 m, 3.06 m); ``smoothed`` runs the filter
    backward too, where the clean boxes after t = 2.4 s are the history, and both its
    filters weigh the width rule's distances by the rule's σ (measured: at most 0.97 m
    off, RMS 0.92 m; the clean boxes' own error at 30 m is 0.85 m); on clean,
    consistent boxes it keeps ``fused``."""
    rendered, truth = crossing_occluder
    rendered, truth = rendered[18:], truth[18:]
    fused, tracked = build_localizer("fused"), build_localizer("tracked")
    smoothed = build_localizer("smoothed")
    rows = []
    for f in rendered:
        d = OracleDetector().detect(f)
        a = fused.localize(d.boxes, d.class_ids, SPEC, f.pose)
        b = tracked.localize(d.boxes, d.class_ids, SPEC, f.pose, t=f.t)
        smoothed.localize(d.boxes, d.class_ids, SPEC, f.pose, t=f.t)
        rows.append((d, a, b))
    out = smoothed.smoothed()
    assert len(out) == len(rendered)
    err_f, err_t, err_s, flagged = [], [], [], []
    for (d, a, b), s, (tx, ty) in zip(rows, out, truth, strict=True):
        if 1 not in d.truth_ids:
            continue
        i = list(d.truth_ids).index(1)
        err_f.append(np.hypot(a.x[i] - tx, a.y[i] - ty))
        err_t.append(np.hypot(b.x[i] - tx, b.y[i] - ty))
        err_s.append(np.hypot(s.x[i] - tx, s.y[i] - ty))
        flagged.append(a.evidence[i] != 0)
    err_f, err_t, err_s = np.array(err_f), np.array(err_t), np.array(err_s)
    flagged = np.array(flagged)
    assert flagged[:5].all() and (~flagged).sum() >= 10

    def rms(e):
        return float(np.sqrt(np.mean(e[flagged] ** 2)))

    assert err_t[flagged].max() > 3.5 and err_f[flagged].max() > 4.0
    assert err_s[flagged].max() < 1.1, np.round(err_s, 2)
    assert rms(err_s) < 0.4 * min(rms(err_t), rms(err_f)), (rms(err_s), rms(err_t))
    assert np.allclose(err_s[~flagged][-10:], err_f[~flagged][-10:])
    smoothed.reset()
    assert smoothed.smoothed() == []


def test_snap_to_lanes_moves_an_off_road_position_along_its_ray():
    """The straight test road: driving lanes from y = -7 to 7 m, sidewalks beyond. A car
    in the far left lane at (-60, -5.25), seen from (-95, 1.75), read 60 m away (its bottom
    hidden: too far) lands on the sidewalk beyond the road; along its ray the nearest
    point on a lane (0.25 m inside its outer edge) is 45.9 m away. Positions on a lane,
    and rays that meet no lane within [0.4 D, 1.6 D + 2], are left alone."""
    from dashtraj.perception.localize import Localized, snap_to_lanes
    from dashtraj.roads import RoadMap
    from render_scene import STRAIGHT_XODR

    road = RoadMap.from_string(STRAIGHT_XODR, name="straight")
    pose = CameraPose(-95.0, 1.75, 1.6, 0.0)
    bearing = np.degrees(np.arctan2(-7.0, 35.0))
    dist = np.array([60.0, 35.7, 30.0])  # too far (off road), right, off road and no lane
    bear = np.array([bearing, bearing, 90.0])
    x, y = place(pose, dist, bear)
    loc = Localized(dist, bear, x, y, np.ones(3), np.ones(3, bool), np.zeros(3, np.int64))
    out = snap_to_lanes(road, pose, loc)
    lane_edge = (1.75 + 7.25) / np.sin(np.radians(-bearing))  # 45.89 m
    assert out.distance_m[0] == pytest.approx(lane_edge, abs=0.3)
    true_d = np.hypot(35.0, 7.0)
    assert abs(out.distance_m[0] - true_d) < 0.5 * (60.0 - true_d)  # 24.3 m off -> 10.2 m
    assert out.distance_m[1:].tolist() == dist[1:].tolist()
    assert (out.x[0], out.y[0]) == pytest.approx(place(pose, out.distance_m[0], bearing))
    assert out.bearing_deg.tolist() == bear.tolist() and out.sigma_m.tolist() == [1.0] * 3


def test_mapped_needs_the_road_map():
    from dashtraj.perception.localize import MappedLocalizer

    loc = build_localizer("mapped")
    assert isinstance(loc, MappedLocalizer) and loc.road_map is None
    loc.localize(np.zeros((0, 4)), np.zeros(0, np.int64), SPEC, CameraPose(0, 0, 1.6, 0), t=0.0)
    with pytest.raises(LocalizationError, match="road map"):
        loc.smoothed()


@pytest.fixture(scope="module")
def cut_cars(gl_available):
    """Cars beside the observer (at (-95, 1.75), heading +x), so close that the image
    border cuts them: 4 m ahead in the next lane (y = 5.25; a Lincoln MKZ, 4.93 m, and a
    Nissan Patrol, 5.18 m), and 6.5 m ahead in the oncoming lane (a Dodge Charger, 5.04 m)."""
    scenes = [(3, -91.0, 5.25, 0.0), (4, -91.0, 5.25, 0.0), (2, -88.5, -1.75, 180.0)]
    frames = [(0.0, (-95.0, 1.75, 0.0), [v]) for v in scenes]
    return render_scene(frames, SPEC), scenes


def test_fit_cut_boxes_places_cars_cut_by_the_border(cut_cars):
    """Measured: ``fused`` reads these border-cut cars 0.94, 1.91 and 0.59 m off (the
    visible part's centre column and lowest pixel are not the car's); re-placed by the
    model of a class-typical car on its lane (`fit_cut_boxes`), from an estimate 2 m off
    along the road, each is 0.25 m off (a car much shorter than the class's 4.76 m, the
    Audi A2's 3.83 m, comes out 0.75–1.0 m off). A clean box is left alone."""
    from dashtraj.perception.localize import CUT_LEFT, CUT_RIGHT, Localized, fit_cut_boxes
    from dashtraj.roads import RoadMap
    from render_scene import STRAIGHT_XODR

    road = RoadMap.from_string(STRAIGHT_XODR, name="straight")
    rendered, scenes = cut_cars
    fused = build_localizer("fused")
    before = []
    for f, (_, tx, ty, _) in zip(rendered, scenes, strict=True):
        d = OracleDetector().detect(f)
        assert len(d.boxes) == 1
        a = fused.localize(d.boxes, d.class_ids, SPEC, f.pose)
        assert a.evidence[0] & (CUT_LEFT | CUT_RIGHT)
        before.append(np.hypot(a.x[0] - tx, a.y[0] - ty))
        for dx in (2.0, -2.0):
            start = Localized(a.distance_m, a.bearing_deg, a.x + dx, a.y, a.sigma_m, a.valid,
                              a.evidence)
            out = fit_cut_boxes(road, SPEC, f.pose, d.boxes, d.class_ids, start)
            assert np.hypot(out.x[0] - tx, out.y[0] - ty) < 0.4, (tx, ty, out.x, out.y)
            assert out.distance_m[0] == pytest.approx(np.hypot(out.x[0] + 95.0,
                                                               out.y[0] - 1.75))
    assert max(before) > 0.9
    clean = Localized(np.array([30.0]), np.array([0.0]), np.array([-65.0]), np.array([1.75]),
                      np.ones(1), np.ones(1, bool), np.zeros(1, np.int64))
    same = fit_cut_boxes(road, SPEC, rendered[0].pose, np.array([[600.0, 300, 700, 400]]),
                         np.zeros(1, np.int64), clean)
    assert same is clean


@pytest.fixture(scope="module")
def strip_scene(gl_available):
    """A car's strip above a nearer, lower car, both cut by the right border: the observer
    at (-95, -5.25) heading +x; an Audi TT (1.35 m high) 4.2 m ahead in the next lane
    (y = -1.75), a BMW X5 (1.75 m) 11.7 m ahead two lanes further (y = 5.25), 15.7 m away,
    its wheels hidden by the TT."""
    from dashtraj.world import catalog

    ids = catalog.identities()
    cars = {1: ids[1], 2: ids[4]}
    assert (cars[1].model.blueprint_id, cars[2].model.blueprint_id) == \
        ("vehicle.audi.tt", "vehicle.bmw.x5")
    frames = [(0.0, (-95.0, -5.25, 0.0), [(1, -90.8, -1.75, 0.0), (2, -83.3, 5.25, 0.0)])]
    return render_scene(frames, SPEC, cars)[0], {1: (-90.8, -1.75), 2: (-83.3, 5.25)}


def test_a_strip_above_a_nearer_car_lies_between_it_and_the_far_reading(strip_scene):
    """Measured: the X5's box is the 48 px above the TT's roof (its lowest row the TT's
    top row), cut by the border, so its bottom row, its height and its width all read far:
    ``fused`` put it at 36.5 m (truth 15.7 m). Between the occluder's range + 1 m and that
    reading (the log-uniform median of the two) it is 14.6 m, 1.3 m off; `fit_cut_boxes`
    then puts it 0.06 m off, taking the hidden bottom row as a bound (the model's lowest
    pixel at or below it). Fitted to the hidden row as if it were the wheels' (the
    evidence bit cleared), the fit lands 4.4 m off."""
    from dashtraj.perception.localize import (
        CUT_RIGHT,
        HIDDEN_BOTTOM,
        FusedLocalizer,
        Localized,
        fit_cut_boxes,
    )
    from dashtraj.render.synthetic import STRAIGHT_XODR
    from dashtraj.roads import RoadMap

    frame, truth = strip_scene
    d = OracleDetector().detect(frame)
    far = int(np.flatnonzero(d.truth_ids == 2)[0])
    near = int(np.flatnonzero(d.truth_ids == 1)[0])
    assert abs(d.boxes[far, 3] - d.boxes[near, 1]) <= 2.0  # its lowest row: the TT's top
    tx, ty = truth[2]

    def err(loc):
        return float(np.hypot(loc.x[far] - tx, loc.y[far] - ty))

    raw = FusedLocalizer(strip_px=None, width_cap=False).localize(d.boxes, d.class_ids, SPEC,
                                                                  frame.pose)
    out = build_localizer("fused").localize(d.boxes, d.class_ids, SPEC, frame.pose)
    assert out.evidence[far] & CUT_RIGHT and out.evidence[far] & HIDDEN_BOTTOM
    assert raw.distance_m[far] > 30.0 and err(raw) > 15.0
    lo = out.distance_m[near] + 1.0
    assert out.distance_m[far] == pytest.approx(np.sqrt(lo * raw.distance_m[far]))
    assert err(out) < 2.0
    assert out.distance_m[near] == pytest.approx(raw.distance_m[near])  # the TT: unchanged
    road = RoadMap.from_string(STRAIGHT_XODR, name="straight")
    fit = fit_cut_boxes(road, SPEC, frame.pose, d.boxes, d.class_ids, out)
    assert err(fit) < 0.5
    blind = Localized(out.distance_m, out.bearing_deg, out.x, out.y, out.sigma_m, out.valid,
                      out.evidence & ~HIDDEN_BOTTOM)
    assert err(fit_cut_boxes(road, SPEC, frame.pose, d.boxes, d.class_ids, blind)) > 2.0


def test_class_diagonals_are_the_catalogs_largest():
    """`width_bound` holds for every vehicle only while each class's diagonal is its
    largest model's."""
    import math

    from dashtraj.perception.localize import CLASS_DIAGONAL_MAX_M
    from dashtraj.world import catalog

    for k, name in enumerate(catalog.VEHICLE_CLASSES):
        diag = max(math.hypot(m.length_m, m.width_m) for m in catalog.models(name))
        assert CLASS_DIAGONAL_MAX_M[k] == pytest.approx(diag, abs=0.01), name


@pytest.fixture(scope="module")
def broadside(gl_available):
    """Cars seen from the side, 35° right of the camera axis (camera at (-95, 0), yaw 0):
    the catalog's widest car, the Ford ambulance (6.70 x 2.30 m), at 6, 10 and 20 m with
    its diagonal across the ray (its widest look), and a car of common size (car 1 of
    `car_identities`) broadside at 27 m."""
    from dashtraj.world import catalog

    amb = catalog.identities()[33]
    assert amb.model.blueprint_id == "vehicle.ford.ambulance"
    cars = {1: car_identities()[1], 5: amb}
    b = np.radians(35.0)
    widest = 125.0 - np.degrees(np.arctan2(2.30, 6.70))
    at = {("amb", d): (5, -95.0 + d * np.cos(b), d * np.sin(b), widest) for d in (6.0, 10.0, 20.0)}
    at["car"] = (1, -95.0 + 27.0 * np.cos(b), 27.0 * np.sin(b), 125.0)
    frames = [(0.0, (-95.0, 0.0, 0.0), [v]) for v in at.values()]
    return dict(zip(at, render_scene(frames, SPEC, cars), strict=True)), at


def test_a_box_wider_than_its_class_allows_has_its_bottom_hidden(broadside):
    """A hedge hides a car's lower part and leaves its top 12 px above it (e12, observer
    1): the bottom row is the hedge's top and the box is short, so both cues read the car
    about three times too far. No car looks as wide as the box there, so the distance is
    cut to the farthest one that could (`width_bound`), flagged `TOO_WIDE`, with the
    rules' σ. Measured: the 27 m car reads 101.1 m (74 m off), cut to 44.2 m (17 m off).
    The catalog's widest car at its widest look is never cut (6 m, cut by the border, 10
    and 20 m: read 19.2 m, the bound 21.0 m)."""
    from dashtraj.perception.localize import TOO_WIDE, FusedLocalizer, width_bound

    frames, at = broadside
    free = FusedLocalizer(width_cap=False)
    fused = build_localizer("fused")
    for key, f in frames.items():
        d = OracleDetector().detect(f)
        assert len(d.boxes) == 1
        if key == "car":
            continue
        a, b = fused.localize(d.boxes, d.class_ids, SPEC, f.pose), \
            free.localize(d.boxes, d.class_ids, SPEC, f.pose)
        assert a.distance_m[0] == b.distance_m[0] and not a.evidence[0] & TOO_WIDE, key
        assert a.distance_m[0] < width_bound(d.boxes, d.class_ids, SPEC, a.bearing_deg)[0]
    f = frames["car"]
    d = OracleDetector().detect(f)
    d.boxes[0, 3] = d.boxes[0, 1] + 12.0  # the hedge: only the top 12 px show
    _, tx, ty, _ = at["car"]
    raw = free.localize(d.boxes, d.class_ids, SPEC, f.pose)
    out = fused.localize(d.boxes, d.class_ids, SPEC, f.pose)
    assert raw.distance_m[0] > 80.0 and not raw.evidence[0] & TOO_WIDE
    bound = width_bound(d.boxes, d.class_ids, SPEC, out.bearing_deg)[0]
    assert out.distance_m[0] == pytest.approx(bound) and out.evidence[0] & TOO_WIDE
    assert out.sigma_m[0] == pytest.approx(HIDDEN_SIGMA_REL * bound)
    assert np.hypot(raw.x[0] - tx, raw.y[0] - ty) > 60.0
    assert np.hypot(out.x[0] - tx, out.y[0] - ty) < 20.0
