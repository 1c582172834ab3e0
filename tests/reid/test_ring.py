"""The ReID set's fixed-lens ring cameras: a rendered window equals that part of the full image."""

from __future__ import annotations

import numpy as np

from dashtraj.datasets.reid import ReidConfig, _Stage, ring_cameras
from dashtraj.render.look import preset
from dashtraj.world import catalog
from dashtraj.world.towns import town_path


def test_window_is_the_centre_of_the_fixed_camera_image(gl_available, tmp_path):
    cfg = ReidConfig(n_ids=2, n_test_ids=1, n_cameras=12, seed=3, fov_deg=90.0,
                     image_size=(640, 480), msaa=0)
    stage = _Stage(cfg, str(town_path("town10")), str(tmp_path))
    ident = catalog.identities()[0]
    x, y, z, yaw = stage.pose
    try:
        views = [stage.camera_pose(c, ident.model) for c in ring_cameras(cfg)]
        far = max(range(len(views)), key=lambda i: ring_cameras(cfg)[i].distance_m)
        pose, (w, h, fov) = views[far]
        assert w < 640 and h == w  # a far camera renders only a window
        # geometry and shading only: camera effects (vignetting, noise) are drawn per
        # rendered image, so they are centred on the window (see the module docstring)
        for view in ((w, h, fov), (640, 480, 90.0)):
            stage.renderer(view).set_look(preset("flat"))
        win = stage.renderer((w, h, fov)).render(pose, [(1, ident, x, y, z, yaw)])
        full = stage.renderer((640, 480, 90.0)).render(pose, [(1, ident, x, y, z, yaw)])
    finally:
        stage.release()
    x0, y0 = (640 - w) // 2, (480 - h) // 2
    part = full.rgb[y0:y0 + h, x0:x0 + w].astype(int)
    diff = np.abs(win.rgb.astype(int) - part)
    assert diff.mean() < 2.0 and np.mean(diff.max(axis=2) > 40) < 0.01
    # the vehicle's box is the full image's box shifted by the window's corner
    bw, bf = win.labels[0].visible_box, full.labels[0].visible_box
    assert np.allclose(np.add(bw, [x0, y0, x0, y0]), bf, atol=1.0)


def test_fixed_lens_crops_shrink_with_distance(gl_available, tmp_path):
    cfg = ReidConfig(n_ids=2, n_test_ids=1, n_cameras=40, seed=0)
    stage = _Stage(cfg, str(town_path("town10")), str(tmp_path))
    model = catalog.identities()[0].model
    cams = ring_cameras(cfg)
    widths = [stage.camera_pose(c, model)[1][0] for c in cams]
    near = [w for c, w in zip(cams, widths, strict=True) if c.distance_m < 6]
    far = [w for c, w in zip(cams, widths, strict=True) if c.distance_m > 12]
    assert near and far and min(near) > max(far)  # same focal length: far = fewer pixels
    zoom = _Stage(ReidConfig(n_ids=2, n_test_ids=1, n_cameras=40, seed=0, fov_deg=None),
                  str(town_path("town10")), str(tmp_path))
    assert {zoom.camera_pose(c, model)[1][:2] for c in cams} == {(256, 256)}
