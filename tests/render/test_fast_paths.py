"""The renderer's fast paths give the same labels as the reference paths.

- silhouettes: all vehicles in one pass (OR-ed layer bits) vs one pass and readback
  per layer of non-overlapping vehicles (``Renderer.silhouette_mode = "layers"``);
- visible boxes/counts from each vehicle's projected box vs a scan of the whole
  instance image;
- one-pass colour+ids+depth (``msaa=0``) vs the separate id pass of the MSAA path:
  identical instance and depth images;
- ``depth=False`` changes nothing but the missing depth image.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from dashtraj.render.scene import Renderer
from render_scene import BIKE, BUS, MOTO, SEDAN, SUV, TRUCK, VAN, identity

MODELS = [SEDAN, SUV, VAN, TRUCK, BUS, MOTO, BIKE]


def random_scene(rng: np.random.Generator, n: int):
    """A camera somewhere on the road and ``n`` vehicles around it (many overlapping,
    some behind the camera, some crossing the image border)."""
    cx = rng.uniform(-95, 60)
    cam = (cx, rng.uniform(-6, 6), rng.uniform(1.2, 3.0), rng.uniform(-40, 40),
           rng.uniform(-8, 3), rng.uniform(-3, 3))  # fmt: skip
    ids = rng.choice(np.arange(1, 10_000), n, replace=False)
    vs = []
    for i in range(n):
        model = MODELS[rng.integers(len(MODELS))]
        rgb = tuple(int(c) for c in rng.integers(0, 256, 3))
        vs.append((int(ids[i]), identity(model, rgb, i), cx + rng.uniform(-15, 70),
                   rng.uniform(-9, 9), 0.0, rng.uniform(-180, 180)))  # fmt: skip
    return cam, vs


@pytest.fixture(scope="module")
def pair(gl_ctx, straight_map):
    a = Renderer(straight_map, 320, 180, 90.0, msaa=0, ctx=gl_ctx)
    b = Renderer(straight_map, 320, 180, 90.0, msaa=2, ctx=gl_ctx)
    yield a, b
    a.release()
    b.release()


def test_a_renderer_draws_in_its_own_context_after_another_was_made(gl_ctx, straight_map):
    """GL calls go to the current context, the last one made: a renderer must make its own
    current (before, after the perception tests had made contexts of their own, the
    session context's renderers drew stray surfaces with garbage ids)."""
    from dashtraj.render.gl import create_context

    rng = np.random.default_rng(3)
    cam, vs = random_scene(rng, 12)
    a = Renderer(straight_map, 320, 180, 90.0, msaa=0, ctx=gl_ctx)
    before = a.render(cam, vs)
    other = create_context()  # now the current context
    b = Renderer(straight_map, 160, 90, 60.0, msaa=0, ctx=other)
    b.render(cam, vs[:3])
    after = a.render(cam, vs)
    assert after.rgb.tobytes() == before.rgb.tobytes()
    assert after.instance.tobytes() == before.instance.tobytes()
    assert after.labels == before.labels
    b.release()
    other.release()
    assert a.render(cam, vs).instance.tobytes() == before.instance.tobytes()
    a.release()


def _reference_visible(instance, vehicles):
    ids = [v[0] for v in vehicles]
    out = []
    for i in ids:
        m = instance == i
        sl = ndimage.find_objects(m.astype(np.int32))
        box = None if not sl else (sl[0][1].start, sl[0][0].start, sl[0][1].stop, sl[0][0].stop)
        out.append((int(m.sum()), box))
    return out


def test_fast_labels_equal_reference_labels(pair):
    fast, ms = pair
    rng = np.random.default_rng(7)
    n_partly = n_hidden = n_layers = 0
    for _ in range(40):
        cam, vs = random_scene(rng, int(rng.integers(1, 25)))
        f = fast.render(cam, vs)
        fast.silhouette_mode = "layers"
        try:
            g = fast.render(cam, vs)
        finally:
            fast.silhouette_mode = "bits"
        assert f.labels == g.labels
        assert f.instance.tobytes() == g.instance.tobytes()
        ref = _reference_visible(f.instance, vs)
        for lb, (count, box) in zip(f.labels, ref, strict=True):
            assert lb.visible_pixels == count and lb.visible_box == box
            if 0 < lb.visible_fraction < 1:
                n_partly += 1
            if lb.visible_pixels == 0 and lb.silhouette_pixels > 0:
                n_hidden += 1
        # the MSAA renderer's separate id/depth pass draws the same ids and depth
        h = ms.render(cam, vs)
        assert h.instance.tobytes() == f.instance.tobytes()
        assert h.depth.tobytes() == f.depth.tobytes()
        assert h.labels == f.labels
        n_layers += len(vs) > 1
    assert n_partly > 20 and n_hidden > 3 and n_layers > 30  # the scenes exercise occlusion


def test_more_than_32_silhouette_layers(gl_ctx, straight_map):
    """Forty vehicles stacked in one spot: one layer each, two bit passes."""
    r = Renderer(straight_map, 160, 90, 90.0, msaa=0, ctx=gl_ctx)
    cam = (-95.0, 1.75, 1.6, 0.0, 0.0, 0.0)
    vs = [(i + 1, identity(SEDAN), -70.0 + 0.3 * i, 1.75, 0.0, 0.0) for i in range(40)]
    f = r.render(cam, vs)
    r.silhouette_mode = "layers"
    g = r.render(cam, vs)
    assert f.labels == g.labels
    assert sum(lb.silhouette_pixels > 0 for lb in f.labels) == 40
    r.release()


def test_depth_readback_is_optional(pair):
    fast, ms = pair
    cam, vs = random_scene(np.random.default_rng(3), 12)
    for r in (fast, ms):
        a = r.render(cam, vs)
        b = r.render(cam, vs, depth=False)
        assert b.depth is None
        assert a.rgb.tobytes() == b.rgb.tobytes() and a.instance.tobytes() == b.instance.tobytes()
        assert a.labels == b.labels


def test_visible_falls_back_to_a_full_scan_when_boxes_miss_pixels():
    """``visible_in_boxes`` never trusts the boxes blindly: pixels outside them trigger a
    scan."""
    from dashtraj.render.labels import visible_in_boxes

    inst = np.zeros((20, 30), np.int32)
    inst[2:5, 3:9] = 70
    inst[10:18, 20:29] = 5
    good = np.array([[20, 10, 29, 18], [3, 2, 9, 5]])
    bad = np.array([[20, 10, 25, 12], [0, 0, 0, 0]])  # too small / empty
    for boxes in (good, bad):
        counts, vboxes = visible_in_boxes(inst, [5, 70], boxes)
        assert counts.tolist() == [72, 18]
        assert vboxes == [(20, 10, 29, 18), (3, 2, 9, 5)]


def test_hull_vertices_project_like_every_vertex(pair):
    """``vehicle_boxes`` with the meshes' hull rows: the same points' hull, the same
    bounds and boxes as projecting every vertex, for vehicles in front of the camera,
    crossing its near plane (cameras inside and just behind vehicles) and behind it."""
    from dashtraj.render.labels import ConvexHull, vehicle_boxes
    from dashtraj.render.scene import as_instances, place

    r = pair[0]
    rng = np.random.default_rng(11)
    crossing = 0
    for k in range(12):
        cam, vs = random_scene(rng, 10)
        if k % 3 == 0:  # the camera inside the first vehicle, looking along it
            _, _, x, y, _, yaw = vs[0]
            cam = (x - 0.5, y, 1.2, yaw, 0.0, 0.0)
        insts = as_instances(vs)
        rows = [r._mesh_rows(v) for v in insts]
        counts = np.array([len(m[1]) for m in rows])
        starts = np.concatenate([[0], np.cumsum(counts)])
        world = np.concatenate([
            np.column_stack(place(v.x, v.y, v.z, np.cos(np.radians(v.yaw_deg)),
                                  np.sin(np.radians(v.yaw_deg)), m[1][:, :3].astype(np.float64)))
            for v, m in zip(insts, rows, strict=True)])  # fmt: skip
        tri = np.concatenate([m[2] + s for m, s in zip(rows, starts[:-1], strict=True)])
        hull = np.concatenate([m[4] + s for m, s in zip(rows, starts[:-1], strict=True)])
        assert len(hull) < 0.25 * len(tri)
        full = vehicle_boxes(r, cam, world[tri], np.concatenate([[0], np.cumsum(
            [len(m[2]) for m in rows])]))  # the triangle list itself
        fast = vehicle_boxes(r, cam, world, starts, hull, tri)
        np.testing.assert_array_equal(fast.boxes, full.boxes)
        np.testing.assert_array_equal(fast.lo, full.lo)
        np.testing.assert_array_equal(fast.hi, full.hi)
        np.testing.assert_array_equal(fast.has, full.has)
        for i in range(len(vs)):
            a = full.uv[full.offsets[i] : full.offsets[i + 1]]
            b = fast.uv[fast.offsets[i] : fast.offsets[i + 1]]
            if len(a) != len(b):  # hull vertices only: the same 2-D hull
                assert len(b) < len(a)
                ha, hb = ConvexHull(a), ConvexHull(b)
                assert hb.volume == pytest.approx(ha.volume, rel=1e-9)
            else:  # clipped whole, as before (or empty: behind the camera)
                crossing += len(a) > 0
                np.testing.assert_array_equal(a, b)
    assert crossing >= 4


def test_vehicles_are_drawn_indexed_with_the_same_triangles(pair):
    """Each vehicle mesh is uploaded once per distinct vertex and drawn through indices
    that rebuild its triangle list row for row; the silhouette indices share a vertex
    per position (the silhouette pass reads positions only)."""
    from dashtraj.render.scene import as_instances

    r = pair[0]
    for model in MODELS:
        inst = as_instances([(1, identity(model, (90, 120, 200)), 0.0, 0.0, 0.0, 0.0)])[0]
        mesh, rows, tri, sil, hull = r._mesh_rows(inst)
        ref = mesh.interleaved(0.0)
        assert np.array_equal(rows[tri], ref)
        assert np.array_equal(rows[sil][:, :3], ref[:, :3])
        assert len(rows) < 0.7 * len(ref)  # flat-shaded: faces share their corners
        assert len(np.unique(sil)) < 0.4 * len(ref)
        assert np.all(np.diff(hull) > 0) and hull[-1] < len(rows)


def test_cached_static_shadows_equal_drawn_ones_and_forget_history(gl_ctx, straight_map):
    """The static casters' shadow depth, cached per (snapped) light box and copied into
    the shadow map, gives the bytes of drawing them every frame; and a frame does not
    depend on the frames before it (the box is a function of the pose)."""
    vehicles = [(i + 1, identity(MODELS[i % len(MODELS)], (60 + 20 * i, 90, 200 - 15 * i), i),
                 -70.0 + 6.0 * i, (-5.25, -1.75, 1.75, 5.25)[i % 4], 0.0, 180.0 * (i % 2))
                for i in range(8)]  # fmt: skip
    cached = Renderer(straight_map, 320, 180, 90.0, msaa=0, ctx=gl_ctx)
    drawn = Renderer(straight_map, 320, 180, 90.0, msaa=0, ctx=gl_ctx)
    assert cached._static_shadow is not None and cached._casters  # llvmpipe: GL 4.5
    assert cached._shadows_on  # the default look: sun and shadows
    for obj in drawn._static_shadow[::-1]:  # the reference draws every frame
        obj.release()
    drawn._static_shadow = None
    hits = 0
    try:
        for i in range(12):
            pose = (-80.0 + 0.3 * i, 1.75, 1.6, 0.5 * i, 0.0, 0.0)
            key = cached._static_shadow_key
            a, b = cached.render(pose, vehicles), drawn.render(pose, vehicles)
            hits += key is not None and key == cached._static_shadow_key
            assert a.rgb.tobytes() == b.rgb.tobytes(), pose
        assert hits >= 3  # nearby poses share the box
        fresh = Renderer(straight_map, 320, 180, 90.0, msaa=0, ctx=gl_ctx)
        assert fresh.render(pose, vehicles).rgb.tobytes() == a.rgb.tobytes()
        fresh.release()
    finally:
        cached.release()
        drawn.release()
