"""The CARLA bridge's conversions with the carla client's own types (no server runs here),
and `carla-record` refusing cleanly when no server answers."""

from __future__ import annotations

import queue
from types import SimpleNamespace

import numpy as np
import pytest

from dashtraj.cli import main
from dashtraj.datasets.carla_bridge import (
    CarlaBridgeError,
    camera_pose,
    image_of_frame,
    image_rgb,
    truth_row,
    vehicle_class_of,
)

carla = pytest.importorskip("carla")


def test_a_carla_transform_is_the_camera_pose_unflipped():
    vehicle = carla.Transform(carla.Location(x=10.0, y=20.0, z=0.1), carla.Rotation(yaw=30.0))
    cam = carla.Transform(vehicle.transform(carla.Location(x=1.0, y=0.0, z=1.6)),
                          carla.Rotation(pitch=-5.0, yaw=30.0))
    x, y, z, yaw, pitch = camera_pose(cam)
    # CARLA's world is dashtraj's: 1 m ahead at yaw 30° is (cos 30°, sin 30°)
    assert (x, y) == pytest.approx((10.0 + np.cos(np.radians(30)), 20.0 + 0.5), abs=1e-5)
    assert (z, yaw, pitch) == pytest.approx((1.7, 30.0, -5.0), abs=1e-5)


def test_a_truth_row_is_the_bounding_box_footprint_in_the_world(tmp_path):
    """CARLA's bounding box sits at an offset from the actor's origin: the row gives the
    centre of the box's bottom face in the world, which the drive's truth reads back."""
    from dashtraj.datasets.drive_truth import read_truth, write_truth

    actor = carla.Transform(carla.Location(x=10.0, y=20.0, z=0.5), carla.Rotation(yaw=90.0))
    bb = carla.BoundingBox(carla.Location(x=0.2, y=0.0, z=0.8), carla.Vector3D(2.3, 1.0, 0.7))
    row = truth_row(42, "target", "vehicle.audi.tt", "car", 1.5, actor, bb)
    # 0.2 m ahead at yaw 90° is +y; the bottom face is 0.8 − 0.7 m above the origin
    assert row[:5] == (1.5, 42, "target", "vehicle.audi.tt", "car")
    assert row[5:] == pytest.approx((10.0, 20.2, 0.6, 90.0, 2.3, 1.0, 0.7), abs=1e-5)
    write_truth(tmp_path / "truth.csv", [row])
    m = read_truth(tmp_path / "truth.csv").at(1.5)
    assert m.vehicle_ids.tolist() == [42] and m.y[0] == pytest.approx(20.2, abs=1e-5)


@pytest.mark.parametrize("type_id, attributes, want", [
    ("vehicle.mercedes.sprinter", {"base_type": "van", "number_of_wheels": "4"}, "car"),
    ("vehicle.carlamotors.firetruck", {"base_type": "truck"}, "truck"),
    ("vehicle.mitsubishi.fusorosa", {"base_type": "Bus"}, "bus"),
    ("vehicle.bh.crossbike", {"number_of_wheels": "2"}, "bicycle"),  # before base_type
    ("vehicle.yamaha.yzf", {"number_of_wheels": "2"}, "motorcycle"),
    ("vehicle.tesla.model3", {}, "car"),
])
def test_a_blueprint_has_a_dashtraj_class(type_id, attributes, want):
    assert vehicle_class_of(type_id, attributes) == want


def test_bgra_bytes_become_rgb():
    bgra = np.zeros((2, 3, 4), np.uint8)
    bgra[..., 0], bgra[..., 1], bgra[..., 2], bgra[..., 3] = 10, 20, 30, 255
    bgra[1, 2] = (1, 2, 3, 255)
    rgb = image_rgb(bgra.tobytes(), 3, 2)
    assert rgb.shape == (2, 3, 3) and rgb.dtype == np.uint8
    assert rgb[0, 0].tolist() == [30, 20, 10] and rgb[1, 2].tolist() == [3, 2, 1]
    with pytest.raises(CarlaBridgeError, match="holds 24 bytes, not 32"):
        image_rgb(bgra.tobytes(), 4, 2)


def test_the_image_of_a_frame_skips_older_ones_and_refuses_newer():
    q: queue.Queue = queue.Queue()
    for f in (5, 6, 7):
        q.put(SimpleNamespace(frame=f))
    assert image_of_frame(q, 6).frame == 6  # frame 5 (before the recording) dropped
    with pytest.raises(CarlaBridgeError, match="sent frame 7 while frame 6"):
        image_of_frame(q, 6)
    with pytest.raises(CarlaBridgeError, match="no camera image for server frame 8"):
        image_of_frame(q, 8, timeout_s=0.05)


def test_carla_record_without_a_server_is_one_line_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "drive"
    assert main(["carla-record", "-o", str(out), "--port", "2999", "--timeout", "0.5",
                 "-q"]) == 2
    err = capsys.readouterr().err
    assert "no CARLA server answered at localhost:2999 within 0.5 s" in err
    assert err.count("\n") == 1 and not out.exists() and not list(tmp_path.iterdir())
