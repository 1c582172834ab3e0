"""Renderer: pinhole agreement with K, exact instance labels, occlusion, orientation,
determinism and image sizes, on a synthetic straight road (tests/render/conftest.py).

The camera stands on the +x-driving lane (y = 1.75) at x = -95, 1.6 m up, looking
along +x unless a test says otherwise."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dashtraj.render.labels import DETECTION_CLASSES, relative_yaw, truncation
from dashtraj.render.meshes import scene_meshes, vehicle_mesh
from dashtraj.render.scene import Renderer, intrinsics, place, project_points
from render_scene import BIKE, BUS, MOTO, SEDAN, STRAIGHT_XODR, SUV, TRUCK, VAN, identity

CAM = (-95.0, 1.75, 1.6, 0.0, 0.0, 0.0)


@pytest.fixture(scope="module")
def renderer(gl_ctx, straight_map):
    r = Renderer(straight_map, 640, 360, 90.0, msaa=4, ctx=gl_ctx)
    yield r
    r.release()


def _label(frame, instance_id):
    return next(lb for lb in frame.labels if lb.instance_id == instance_id)


def test_intrinsics_follow_carla():
    k = intrinsics(1280, 720, 90.0)
    assert k[0, 0] == pytest.approx(640.0) and k[1, 1] == pytest.approx(640.0)
    assert (k[0, 2], k[1, 2]) == (640.0, 360.0)


def test_place_turns_vehicle_frame_points_by_the_yaw():
    # a vehicle at (10, 20, 1) facing +y (yaw 90 deg): its nose (x forward) points along +y,
    # its right side (y right in CARLA's left-handed frame) along -x
    p = np.array([[2.0, 0.0, 0.5], [0.0, 1.0, 0.0]])
    x, y, z = place(10.0, 20.0, 1.0, math.cos(math.pi / 2), math.sin(math.pi / 2), p)
    assert np.allclose(np.column_stack([x, y, z]), [[10.0, 22.0, 1.5], [9.0, 20.0, 1.0]])
    # per-point poses broadcast (as the renderer places many vehicles in one product)
    x, y, z = place(np.array([0.0, 5.0]), np.zeros(2), np.zeros(2), np.array([1.0, -1.0]),
                    np.zeros(2), np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0]]))
    assert np.allclose(np.column_stack([x, y, z]), [[1.0, 2.0, 3.0], [4.0, -2.0, 3.0]])


def test_known_point_projects_to_the_k_pixel(gl_ctx, straight_map, monkeypatch):
    """A 20 cm marker cube centred on a known 3-D point lands where K says (< 0.5 px)."""
    from dashtraj.render import scene
    from dashtraj.render.meshes import box

    cube = box((-0.1, -0.1, 0.0), (0.1, 0.1, 0.2), (1.0, 1.0, 1.0))
    monkeypatch.setattr(scene, "vehicle_mesh", lambda model, rgb: cube)
    w, h, fov = 800, 600, 70.0
    r = Renderer(straight_map, w, h, fov, msaa=0, ctx=gl_ctx)
    cam = (-90.0, 0.5, 1.7, 10.0, -3.0, 2.0)
    rng = np.random.default_rng(1)
    for _ in range(6):
        p = np.array([-90.0 + rng.uniform(8, 15), 0.5 + rng.uniform(-4, 4), rng.uniform(0.5, 3)])
        uv, z = project_points(p, cam, r.k)
        assert z[0] > 0
        f = r.render(cam, [(7, identity(SEDAN), p[0], p[1], p[2] - 0.1, 0.0)])
        rows, cols = np.nonzero(f.instance == 7)
        assert len(rows) > 20
        centre = np.array([cols.mean() + 0.5, rows.mean() + 0.5])  # pixel centres
        assert np.abs(centre - uv[0]).max() < 0.5, (centre, uv[0])
    r.release()


def test_visible_box_tightly_bounds_instance_pixels(renderer):
    vs = [
        (3, identity(SEDAN), -80.0, 1.75, 0.0, 0.0),
        (9, identity(SUV), -70.0, -1.75, 0.0, 180.0),
        (4, identity(VAN), -75.0, 5.25, 0.0, 10.0),
    ]
    f = renderer.render(CAM, vs)
    assert f.rgb.shape == (360, 640, 3) and f.rgb.dtype == np.uint8
    assert f.instance.shape == (360, 640) and f.instance.dtype == np.int32
    assert f.depth.shape == (360, 640) and f.depth.dtype == np.float32
    assert set(np.unique(f.instance)) == {0, 3, 4, 9}
    for lb in f.labels:
        rows, cols = np.nonzero(f.instance == lb.instance_id)
        assert lb.visible_box == (cols.min(), rows.min(), cols.max() + 1, rows.max() + 1)
        assert lb.visible_pixels == len(rows)
        sb = lb.silhouette_box
        assert sb[0] <= lb.visible_box[0] and sb[1] <= lb.visible_box[1]
        assert sb[2] >= lb.visible_box[2] and sb[3] >= lb.visible_box[3]
        pb = lb.projected_box
        assert pb[0] <= sb[0] + 1 and pb[2] >= sb[2] - 1  # vertex bound contains the pixels
    unoccluded = _label(f, 3)
    assert unoccluded.visible_fraction == 1.0 and unoccluded.truncation == 0.0
    # depth at the sedan's pixels: between its rear (12.7 m) and front (17.3 m)
    d = f.depth[f.instance == 3]
    assert d.min() > 12.6 and d.max() < 17.4
    assert np.isinf(f.depth[0, 320])  # sky straight up the road


def test_vehicle_hidden_behind_a_truck_has_no_visible_box(renderer):
    truck = (1, identity(TRUCK), -84.0, 1.75, 0.0, 0.0)
    hidden = (2, identity(SEDAN), -70.0, 1.75, 0.0, 0.0)
    f = renderer.render(CAM, [truck, hidden])
    lb = _label(f, 2)
    assert lb.visible_box is None and lb.visible_pixels == 0 and lb.visible_fraction == 0.0
    assert lb.silhouette_box is not None and lb.silhouette_pixels > 100
    assert not lb.in_view
    assert _label(f, 1).visible_fraction == 1.0
    assert not np.any(f.instance == 2)


def test_partly_hidden_vehicle_fraction(renderer):
    bus = (1, identity(BUS), -80.0, 5.25, 0.0, 0.0)
    car = (2, identity(SEDAN), -70.0, 3.5, 0.0, 0.0)
    f = renderer.render(CAM, [bus, car])
    lb = _label(f, 2)
    assert 0.0 < lb.visible_fraction < 1.0
    assert lb.visible_fraction == lb.visible_pixels / lb.silhouette_pixels


@pytest.mark.parametrize(
    ("yaw", "x", "y", "expected"),
    [
        (0.0, -80.0, 1.75, "car_back"),  # ahead, driving away
        (180.0, -75.0, -1.75, "car_front"),  # oncoming
        (90.0, -80.0, 1.0, "car_side"),  # crossing
        (-90.0, -80.0, 1.0, "car_side"),
    ],
)
def test_orientation_labels(renderer, yaw, x, y, expected):
    f = renderer.render(CAM, [(5, identity(SEDAN), x, y, 0.0, yaw)])
    lb = f.labels[0]
    assert lb.detection_class == expected
    assert DETECTION_CLASSES[lb.detection_class_id] == expected
    assert lb.in_view


@pytest.mark.parametrize(
    ("model", "cls"),
    [(VAN, "car"), (TRUCK, "truck"), (BUS, "bus"), (MOTO, "motorcycle"), (BIKE, "bicycle")],
)
def test_classes(renderer, model, cls):
    f = renderer.render(CAM, [(1, identity(model), -75.0, 1.75, 0.0, 0.0)])
    assert f.labels[0].detection_class == f"{cls}_back"
    assert f.labels[0].visible_fraction == 1.0


def test_front_and_back_look_different(renderer):
    """Head lamps (white) at the front, tail lamps (red) at the back (both ends carry a
    light number plate, so the back has some white too, fewer than the front)."""
    back = renderer.render(CAM, [(1, identity(SEDAN, (40, 40, 40)), -85.0, 1.75, 0.0, 0.0)])
    front = renderer.render(CAM, [(1, identity(SEDAN, (40, 40, 40)), -85.0, 1.75, 0.0, 180.0)])

    def lamp_pixels(f, pred):
        px = f.rgb[f.instance == 1].astype(int)
        return int(pred(px).sum())

    def red(px):
        return (px[:, 0] > 150) & (px[:, 1] < 60)

    def white(px):
        return (px > 200).all(axis=1)

    assert lamp_pixels(back, red) > 20 and lamp_pixels(front, red) == 0
    assert lamp_pixels(front, white) > lamp_pixels(back, white) + 20


def test_renders_are_byte_identical(gl_ctx, straight_map):
    vs = [
        (1, identity(BUS), -75.0, -5.25, 0.0, 180.0),
        (2, identity(SEDAN), -82.0, 1.75, 0.0, 3.0),
        (3, identity(MOTO), -78.0, 5.0, 0.0, 20.0),
    ]
    a = Renderer(straight_map, 320, 200, 75.0, msaa=4, ctx=gl_ctx)
    f1 = a.render(CAM, vs)
    f2 = a.render(CAM, vs)
    b = Renderer(straight_map, 320, 200, 75.0, msaa=4, ctx=gl_ctx)
    f3 = b.render(CAM, vs)
    for g in (f2, f3):
        assert f1.rgb.tobytes() == g.rgb.tobytes()
        assert f1.instance.tobytes() == g.instance.tobytes()
        assert f1.depth.tobytes() == g.depth.tobytes()
        assert f1.labels == g.labels
    a.release()
    b.release()


@pytest.mark.parametrize("msaa", [0, 4])
def test_pass_timing_changes_no_byte(gl_ctx, straight_map, msaa):
    """``Renderer.pass_times`` (fences between passes) times every pass of the frame and
    leaves rgb, ids, depth and labels as they are without it."""
    vs = [(1, identity(BUS), -75.0, -5.25, 0.0, 180.0), (2, identity(SEDAN), -82.0, 1.75, 0.0, 3.0)]
    r = Renderer(straight_map, 320, 200, 75.0, msaa=msaa, ctx=gl_ctx)
    try:
        f1 = r.render(CAM, vs)
        r.pass_times = {}
        f2 = r.render(CAM, vs)
        times, r.pass_times = r.pass_times, None
    finally:
        r.release()
    for a in ("rgb", "instance", "depth"):
        assert getattr(f1, a).tobytes() == getattr(f2, a).tobytes()
    assert f1.labels == f2.labels
    colour = "colour + ids + depth" if msaa == 0 else "colour (MSAA)"
    for name in (colour, "shadow map", "sky", "readback", "labels: silhouette pass"):
        assert times[name] > 0.0, times


@pytest.mark.parametrize(
    ("w", "h", "fov"), [(1280, 720, 90.0), (333, 217, 60.0), (200, 400, 110.0)]
)
def test_sizes_and_fovs(gl_ctx, straight_map, w, h, fov):
    r = Renderer(straight_map, w, h, fov, msaa=2, ctx=gl_ctx)
    f = r.render(CAM, [(1, identity(SEDAN), -80.0, 1.75, 0.0, 0.0)])
    assert f.rgb.shape == (h, w, 3) and f.instance.shape == (h, w)
    lb = f.labels[0]
    uv, _ = project_points(np.array([[-80.0, 1.75, 0.7]]), CAM, r.k)
    x0, y0, x1, y1 = lb.visible_box
    assert x0 <= uv[0, 0] <= x1 and y0 <= uv[0, 1] <= y1
    assert lb.visible_fraction == 1.0
    r.release()


def test_truncated_vehicle_at_the_border(renderer):
    f = renderer.render(CAM, [(1, identity(SEDAN), -89.0, -2.5, 0.0, 0.0)])
    lb = f.labels[0]
    assert 0.0 < lb.truncation < 1.0
    assert lb.visible_box[0] == 0  # cut by the left border
    assert lb.projected_box[0] < 0
    behind = renderer.render(CAM, [(1, identity(SEDAN), -105.0, 1.75, 0.0, 0.0)]).labels[0]
    assert behind.truncation == 1.0 and behind.silhouette_box is None and not behind.in_view


def test_truncation_of_polygons():
    sq = np.array([[-10.0, 0.0], [10.0, 0.0], [10.0, 10.0], [-10.0, 10.0]])
    assert truncation(sq, 100, 100) == pytest.approx(0.5)
    assert truncation(sq + 20.0, 100, 100) == 0.0
    assert truncation(sq - 50.0, 100, 100) == 1.0


def test_truncation_against_a_monte_carlo_estimate():
    """The share of the points' hull outside the image against a Monte-Carlo estimate
    (the hull's area from the shoelace formula against qhull's own)."""
    from scipy.spatial import ConvexHull, Delaunay

    from dashtraj.render.labels import _poly_area

    rng = np.random.default_rng(5)
    for _ in range(20):
        pts = rng.normal(size=(int(rng.integers(3, 200)), 2)) * rng.uniform(20, 200) + 50
        ref = ConvexHull(pts)
        assert _poly_area(pts[ref.vertices]) == pytest.approx(ref.volume, rel=1e-12)
        samples = rng.uniform(pts.min(0), pts.max(0), size=(40_000, 2))
        inside_hull = Delaunay(pts[ref.vertices]).find_simplex(samples) >= 0
        in_image = ((samples >= 0) & (samples <= [120, 90])).all(axis=1)
        expected = 1.0 - (inside_hull & in_image).sum() / inside_hull.sum()
        assert truncation(pts, 120, 90) == pytest.approx(expected, abs=0.02)
    line = np.array([[-10.0, 5.0], [10.0, 5.0], [20.0, 5.0]])  # collinear: share of points
    assert truncation(line, 100, 100) == pytest.approx(1 / 3)


def test_relative_yaw_sign_and_wrap():
    assert relative_yaw((0, 0), (10, 0), 0.0) == pytest.approx(0.0)
    assert relative_yaw((0, 0), (0, 10), 0.0) == pytest.approx(-90.0)
    assert abs(relative_yaw((0, 0), (10, 0), 179.0 + 2.0)) == pytest.approx(179.0)


def test_scene_meshes_cached_and_deterministic(straight_map):
    a = scene_meshes(straight_map, seed=0)
    assert scene_meshes(straight_map, seed=0) is a
    from dashtraj.render.meshes import build_scene_meshes

    b = build_scene_meshes(straight_map, seed=0)
    assert a.buildings.positions.tobytes() == b.buildings.positions.tobytes()
    assert a.buildings.n_vertices > 0 and a.marks.n_vertices > 0
    # buildings keep clear of the road: |y| > 6.5 m (road) + 3 m (sidewalk) on this map
    y = a.buildings.positions[:, 1]
    assert np.all(np.abs(y) > 9.5 + 2.9)


def test_a_map_read_again_gets_the_scene_already_built(straight_map):
    """Each renderer opens its recording's map anew: a `RoadMap` of the same document gets
    the same (read-only) scene; another document, seed or sample step builds its own."""
    from dashtraj.render import meshes
    from dashtraj.roads import RoadMap

    a = scene_meshes(straight_map, seed=0)
    again = RoadMap.from_string(STRAIGHT_XODR, name="the same bytes")
    assert again.opendrive.sha256 == straight_map.opendrive.sha256 != ""
    assert scene_meshes(again, seed=0) is a
    assert scene_meshes(again, seed=1) is not a
    assert scene_meshes(again, seed=0, clutter=False) is not a
    coarser = RoadMap.from_string(STRAIGHT_XODR, sample_step_m=straight_map.sample_step_m * 2)
    assert scene_meshes(coarser, seed=0) is not a
    other = RoadMap.from_string(STRAIGHT_XODR + "<!-- the same roads, other bytes -->")
    assert other.opendrive.sha256 != straight_map.opendrive.sha256
    assert scene_meshes(other, seed=0) is not a
    with pytest.raises(ValueError, match="read-only"):
        a.buildings.positions[0, 0] = 1.0
    # the last SCENES_KEPT are kept: after as many others, it is built anew, equal
    for seed in range(2, 2 + meshes.SCENES_KEPT):
        scene_meshes(again, seed=seed)
    b = scene_meshes(again, seed=0)
    assert b is not a and b.props.positions.tobytes() == a.props.positions.tobytes()


def test_a_scene_is_kept_as_a_file_that_other_processes_read(straight_map, tmp_path,
                                                              monkeypatch):
    """The scene of a map read from bytes goes to the cache folder; a process without it in
    memory reads the file (equal to the last bit) instead of building; a file that is not
    whole is built again and rewritten; a folder that cannot be written builds in memory;
    another seed or other code is another file; old files are pruned."""
    import os
    import subprocess
    import sys

    from dashtraj import cache
    from dashtraj.render import meshes

    monkeypatch.setenv("DASHTRAJ_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(meshes, "_SCENES_BY_CONTENT", type(meshes._SCENES_BY_CONTENT)())
    built = meshes.build_scene_meshes(straight_map, 0, True)
    path = meshes.scene_file(straight_map, 0, True)
    assert path.parent == tmp_path / "cache" / "scenes" and not path.exists()
    a = scene_meshes(straight_map, seed=0)
    assert path.is_file() and not list(path.parent.glob(".*.tmp"))

    def same(x, y):
        return x.extent == y.extent and all(
            (getattr(x, p) is None) == (getattr(y, p) is None) and (getattr(x, p) is None or all(
                getattr(getattr(x, p), f).tobytes() == getattr(getattr(y, p), f).tobytes()
                and getattr(getattr(x, p), f).dtype == getattr(getattr(y, p), f).dtype
                for f in ("positions", "normals", "colors")))
            for p in ("ground", "buildings", "marks", "props"))

    assert same(a, built)
    # another process (as a --workers one) reads the file: it never builds
    code = ("import sys; from dashtraj.render import meshes; from dashtraj.roads import "
            "RoadMap\n"
            "def no(*a, **k): raise SystemExit('built')\n"
            "meshes.build_scene_meshes = no\n"
            "s = meshes.scene_meshes(RoadMap.from_string(sys.stdin.read()), seed=0)\n"
            "print(len(s.props.positions), s.props.positions.sum(dtype='float64'))")
    out = subprocess.run([sys.executable, "-c", code], input=STRAIGHT_XODR, text=True,
                         capture_output=True, check=True).stdout.split()
    assert int(out[0]) == len(built.props.positions)
    assert float(out[1]) == float(built.props.positions.sum(dtype="float64"))
    # in this process: from the file once the memory has forgotten it, equal, read-only
    monkeypatch.setattr(meshes, "_SCENES_BY_CONTENT", type(meshes._SCENES_BY_CONTENT)())
    calls = []
    real = meshes.build_scene_meshes
    monkeypatch.setattr(meshes, "build_scene_meshes",
                        lambda *a, **k: calls.append(a) or real(*a, **k))
    b = scene_meshes(straight_map, seed=0)
    assert b is not a and same(b, built) and calls == []
    with pytest.raises(ValueError, match="read-only"):
        b.ground.positions[0, 0] = 1.0
    # a cut file is built again and written whole
    path.write_bytes(path.read_bytes()[:1000])
    monkeypatch.setattr(meshes, "_SCENES_BY_CONTENT", type(meshes._SCENES_BY_CONTENT)())
    assert same(scene_meshes(straight_map, seed=0), built) and len(calls) == 1
    assert meshes._read_scene(path) is not None
    # another seed, clutter off or other code: other files
    assert meshes.scene_file(straight_map, 1, True) != path
    assert meshes.scene_file(straight_map, 0, False) != path
    monkeypatch.setattr(cache, "_CODE_SHA256", ["other code"])
    assert meshes.scene_file(straight_map, 0, True) != path
    monkeypatch.undo()
    # a cache folder that cannot be written (a file in its place): built, nothing written
    blocked = tmp_path / "blocked"
    blocked.write_text("not a folder")
    monkeypatch.setenv("DASHTRAJ_CACHE", str(blocked))
    monkeypatch.setattr(meshes, "_SCENES_BY_CONTENT", type(meshes._SCENES_BY_CONTENT)())
    assert same(scene_meshes(straight_map, seed=0), built)
    # only the last SCENE_FILES_KEPT used are kept
    monkeypatch.setenv("DASHTRAJ_CACHE", str(tmp_path / "few"))
    monkeypatch.setattr(meshes, "SCENE_FILES_KEPT", 2)
    monkeypatch.setattr(meshes, "_SCENES_BY_CONTENT", type(meshes._SCENES_BY_CONTENT)())
    for seed in (0, 1, 2):
        scene_meshes(straight_map, seed=seed)
        os.utime(meshes.scene_file(straight_map, seed, True), (1e9 + seed, 1e9 + seed))
    kept = {p.name for p in (tmp_path / "few" / "scenes").glob("scene-*.npz")}
    assert kept == {meshes.scene_file(straight_map, s, True).name for s in (1, 2)}


def test_vehicle_meshes_fit_their_dimensions():
    for model in (SEDAN, SUV, VAN, TRUCK, BUS):
        p = vehicle_mesh(model, (10, 20, 30)).positions
        assert p[:, 0].min() >= -model.length_m / 2 - 0.05
        assert p[:, 0].max() <= model.length_m / 2 + 0.05
        assert np.abs(p[:, 1]).max() <= model.width_m / 2 + 0.05
        assert p[:, 2].min() >= 0.0 and p[:, 2].max() <= model.height_m + 1e-6
        assert math.isclose(p[:, 2].max(), model.height_m, abs_tol=0.02)


def test_a_sample_count_the_context_cannot_render_is_refused(gl_ctx, straight_map):
    from dashtraj.errors import DashtrajError
    from dashtraj.render.scene import Renderer

    most = int(gl_ctx.max_samples)
    for bad in (3, 2 * most):  # not a power of two; more than the context takes
        with pytest.raises(DashtrajError, match=rf"msaa {bad}: .* up to {most} samples"):
            Renderer(straight_map, 64, 36, 90.0, msaa=bad, ctx=gl_ctx)
    Renderer(straight_map, 64, 36, 90.0, msaa=most, ctx=gl_ctx).release()
