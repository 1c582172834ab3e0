"""A drive's truth.csv: read and checked line by line, interpolated between its rows, and
projected into a camera as truth boxes with occlusion by nearer vehicles."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dashtraj.cli import main
from dashtraj.datasets.drive import Drive, DriveError
from dashtraj.datasets.drive_truth import (
    TRUTH_COLUMNS,
    TruthError,
    TruthMoment,
    read_truth,
    truth_frame,
    write_truth,
)
from dashtraj.world.camera import CameraSpec, box_corners, project, world_to_camera


def _tiny_drive(root):
    """A drive of one observer on town01 with two grey 32 x 24 images."""
    from PIL import Image

    from dashtraj.datasets.drive import DrivePose, write_drive
    from dashtraj.world.towns import town_path

    poses = [DrivePose(7, f, 0.1 * f, 100.0, 5.0, 1.6, 90.0, 0.0) for f in (0, 1)]
    write_drive(root, town_path("town01"), CameraSpec(width_px=32, height_px=24), poses)
    (root / "7").mkdir()
    for f in (0, 1):
        Image.new("RGB", (32, 24), (90, 90, 90)).save(root / "7" / f"{f:06d}.png")
    return root


ROW = (0.0, 5, "agent", "vehicle.audi.a2", "car", 10.0, 2.0, 0.0, 90.0, 1.9, 0.9, 0.75)


def _write(path, rows):
    write_truth(path, rows)
    return path


def test_rows_round_trip_and_interpolate_between_times(tmp_path):
    rows = [ROW, (1.0, 5, "agent", "vehicle.audi.a2", "car", 12.0, 4.0, 1.0, -170.0, 1.9, 0.9,
                  0.75),
            (0.5, 9, "target", "vehicle.bh.crossbike", "bicycle", 0.0, 0.0, 0.0, 0.0, 0.8,
             0.3, 0.8),
            (3.0, 9, "target", "vehicle.bh.crossbike", "bicycle", 9.0, 0.0, 0.0, 0.0, 0.8,
             0.3, 0.8)]
    truth = read_truth(_write(tmp_path / "truth.csv", rows))
    assert truth.vehicle_ids == [5, 9] and truth.role(9) == "target"
    assert truth.vehicle_class(9) == "bicycle"
    m = truth.at(0.25)  # vehicle 9 starts at 0.5
    assert m.vehicle_ids.tolist() == [5]
    assert (m.x[0], m.y[0], m.z[0]) == pytest.approx((10.5, 2.5, 0.25))
    # 90° to -170° is 100° the short way round: a quarter of it is 115°
    assert m.yaw[0] == pytest.approx(115.0)
    assert truth.at(1.0).x.tolist() == [12.0]  # a row's own time (vehicle 9 absent)
    # vehicle 9's rows are 2.5 s apart, more than MAX_GAP_S: absent between them
    assert truth.at(2.0).vehicle_ids.tolist() == []
    assert truth.at(3.0 + 1e-9).vehicle_ids.tolist() == [9]
    assert truth.at(-1.0).vehicle_ids.tolist() == []


@pytest.mark.parametrize("text, message", [
    ("t,vehicle_id\n0,1\n", "missing column 'role'"),
    (",".join(TRUTH_COLUMNS) + "\n0,1,a,b,car,1,2,x,0,1,1,1\n",
     "line 2: vehicle_id must be an integer"),
    (",".join(TRUTH_COLUMNS) + "\n0,1,a,b,car,1,2,0,nan,1,1,1\n", "line 2: numbers must be finite"),
    (",".join(TRUTH_COLUMNS) + "\n0,1,a,b,car,1,2,0,0,1,0,1\n",
     "line 2: half extents must be > 0 m"),
    (",".join(TRUTH_COLUMNS) + "\n0,1,a,b,tram,1,2,0,0,1,1,1\n",
     "line 2: vehicle_class 'tram' is not one of"),
    (",".join(TRUTH_COLUMNS) + "\n0,1,a,b,car,1,2,0,0,1,1,1\n1,1,a,b,bus,1,2,0,0,1,1,1\n",
     "line 3: vehicle 1 is a bus here and a car on line 2"),
    (",".join(TRUTH_COLUMNS) + "\n0,1,a,b,car,1,2,0,0,1,1,1\n0,1,a,b,van,1,2,0,0,1,1,1\n",
     "line 3: vehicle 1 has two rows at t 0"),
    (",".join(TRUTH_COLUMNS) + "\n", "truth.csv: no rows"),
])
def test_bad_truth_is_one_line_naming_the_line(tmp_path, capsys, text, message):
    root = _tiny_drive(tmp_path / "d")
    (root / "truth.csv").write_text(text)
    with pytest.raises(TruthError) as exc:
        read_truth(root / "truth.csv")
    assert message in str(exc.value)
    with pytest.raises(DriveError):
        Drive.open(root)
    out = tmp_path / "x.db"
    assert main(["perceive", str(root), "-o", str(out), "-q"]) == 2
    err = capsys.readouterr().err
    assert message in err and "truth.csv" in err and err.count("\n") == 1
    assert not out.exists()


def _moment(*cars):
    """Cars (vehicle_id, x, y, yaw, class) of a typical size standing at z = 0."""
    n = len(cars)
    return TruthMoment(np.array([c[0] for c in cars], np.int64), tuple(c[4] for c in cars),
                       np.array([c[1] for c in cars], float), np.array([c[2] for c in cars], float),
                       np.zeros(n), np.array([c[3] for c in cars], float), np.full(n, 2.3),
                       np.full(n, 0.95), np.full(n, 0.75))


CAM = CameraSpec(width_px=640, height_px=360, fov_deg=90.0)
POSE = (0.0, 0.0, 1.6, 0.0, 0.0)  # camera at the origin, 1.6 m up, looking along +x


def test_a_lone_car_is_the_projection_of_its_box():
    inst, labels, vids = truth_frame(CAM, POSE, _moment((4, 15.0, 1.0, 0.0, "car")))
    assert vids == (4,)
    (lab,) = labels
    corners = box_corners([15.0], [1.0], [0.0], [0.0], [4.6], [1.9], [1.5])[0]
    uv = project(CAM, world_to_camera(corners, POSE[:3], 0.0))
    want = (uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max())
    assert lab.visible_box == pytest.approx(want, abs=1.0)
    assert lab.detection_class == "car_back" and lab.visible_fraction == 1.0
    assert lab.truncation == 0.0 and lab.distance_m == pytest.approx(math.hypot(15, 1))
    assert (inst == lab.instance_id).sum() == lab.visible_pixels > 1000
    # its own camera never sees the observer, by its id or by carrying the camera (1 m
    # ahead of its centre, whatever id the truth gives it), and nothing behind the camera
    assert truth_frame(CAM, POSE, _moment((4, 15.0, 1.0, 0.0, "car")), exclude=4)[1] == []
    assert truth_frame(CAM, POSE, _moment((9, -1.0, 0.0, 0.0, "car")))[1] == []
    assert len(truth_frame(CAM, POSE, _moment((9, 3.0, 2.5, 0.0, "car")))[1]) == 1  # beside
    assert truth_frame(CAM, POSE, _moment((4, -15.0, 1.0, 0.0, "car")))[1] == []


def test_a_nearer_car_hides_the_one_behind_it():
    _, labels, vids = truth_frame(CAM, POSE, _moment((1, 30.0, 0.0, 180.0, "car"),
                                                     (2, 10.0, 0.3, 0.0, "truck")))
    by = dict(zip(vids, labels, strict=True))
    near, far = by[2], by[1]
    assert near.visible_fraction == 1.0 and near.detection_class == "truck_back"
    assert far.detection_class == "car_front" and far.visible_fraction < 0.2
    # what shows of the far car is above the near one's roof
    assert far.visible_box[3] <= near.visible_box[1] + 1
    # the far car's box as drawn alone is whole
    assert far.silhouette_box[3] > near.visible_box[1] + 5


def test_a_car_beside_the_camera_is_cut_at_the_image_border():
    _, (lab,), _ = truth_frame(CAM, POSE, _moment((3, 2.0, 3.0, 0.0, "car")))
    assert lab.visible_box[0] > 0 and lab.visible_box[2] == CAM.width_px
    assert 0.2 < lab.truncation < 1.0


def test_depth_round_trips_through_carlas_encoding():
    from dashtraj.datasets.drive_truth import decode_depth, encode_depth

    d = np.array([[0.0, 0.5, 12.345], [999.9, np.inf, 2000.0]], np.float32)
    rgb = encode_depth(d)
    assert rgb.dtype == np.uint8 and rgb.shape == (2, 3, 3)
    back = decode_depth(rgb)
    assert back[0] == pytest.approx([0.0, 0.5, 12.345], abs=1e-4)
    assert back[1] == pytest.approx([999.9, 1000.0, 1000.0], abs=1e-4)
    # CARLA's formula: (R + 256 G + 65536 B) / (256³ − 1) × 1000 m
    r, g, b = (int(c) for c in rgb[0, 2])
    assert (r + 256 * g + 65536 * b) / (256 ** 3 - 1) * 1000 == pytest.approx(12.345, abs=1e-4)


def _depth_of(spec, pose, wall_m=None, road=True):
    """A depth image of a flat road (camera 1.6 m up, level) and, optionally, a wall
    across the view ``wall_m`` ahead."""
    f = spec.focal_px
    v = np.arange(spec.height_px) + 0.5 - spec.height_px / 2.0
    d = np.full((spec.height_px, spec.width_px), np.inf)
    below = v > 0
    if road:
        d[below, :] = (pose[2] * f / v[below])[:, None]
    if wall_m is not None:
        d = np.minimum(d, wall_m)
    return d


def test_with_depth_a_car_is_its_pixels_and_a_wall_hides_it():
    # a camera 3 m up (a truck's) sees a car 15 m ahead whose rear face alone is in the
    # depth image (as if the car were that panel): the box's hull also takes in its top
    pose = (0.0, 0.0, 3.0, 0.0, 0.0)
    m = _moment((4, 15.0, 1.0, 0.0, "car"))
    depth = _depth_of(CAM, pose)
    corners = box_corners([15.0], [1.0], [0.0], [0.0], [4.6], [1.9], [1.5])[0]
    uv = project(CAM, world_to_camera(corners, pose[:3], 0.0))
    rear = uv[[2, 3, 6, 7]]  # the rear face (x = 12.7 m)
    u0, v0, u1, v1 = rear[:, 0].min(), rear[:, 1].min(), rear[:, 0].max(), rear[:, 1].max()
    depth[int(v0):int(np.ceil(v1)), int(u0):int(np.ceil(u1))] = 12.7
    _, (hull,), _ = truth_frame(CAM, pose, m)
    _, (lab,), _ = truth_frame(CAM, pose, m, depth=depth)
    # the road below the panel is not the car (GROUND_EPS_M): its box's bottom is a pixel
    # or two above the panel's
    assert lab.visible_box == pytest.approx((u0, v0, u1, v1), abs=2.0)
    assert hull.visible_box[1] <= lab.visible_box[1] - 9  # the top face: 10 px
    assert lab.visible_fraction == 1.0
    # a wall 10 m ahead hides it whole: no pixel is the car's, its silhouette is hidden
    _, (hid,), _ = truth_frame(CAM, pose, m, depth=_depth_of(CAM, pose, wall_m=10.0))
    assert hid.visible_box is None and hid.visible_fraction == 0.0 and hid.silhouette_pixels


def test_a_drive_gets_no_randomized_look_in_a_detection_set(tmp_path, capsys):
    root = _tiny_drive(tmp_path / "d")
    write_truth(root / "truth.csv", [ROW])
    out = tmp_path / "set"
    assert main(["detection-dataset", str(root), "-o", str(out), "--randomize", "-q"]) == 2
    err = capsys.readouterr().err
    assert "is a drive: its images are what they are" in err and err.count("\n") == 1
    assert not out.exists()
