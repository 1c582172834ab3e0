"""Street clutter (negatives: never labelled, never on a driving lane, deterministic from
the scene seed) and the rounded per-class vehicles (catalog dimensions, glass all round,
lamps and plates; contact shadows that change pixels but never ids or depth)."""

from __future__ import annotations

import numpy as np
import pytest

from carla_maps import load_carla_map
from dashtraj.render import clutter as clutter_mod
from dashtraj.render.meshes import (
    MAT_FOLIAGE,
    MAT_GLASS,
    MAT_LAMP,
    MAT_METAL,
    MAT_TYRE,
    build_scene_meshes,
    shadow_caster_mesh,
    vehicle_mesh,
)
from dashtraj.render.synthetic import (
    BIKE,
    BUS,
    MOTO,
    SEDAN,
    STRAIGHT_XODR,
    SUV,
    TRUCK,
    VAN,
    identity,
)
from dashtraj.render.vehicle_shapes import contact_shadow_mesh
from dashtraj.roads import RoadMap
from dashtraj.roads.types import LaneType
from dashtraj.world.catalog import models as catalog_models


def _clutter_only(road_map, seed):
    lane_pts = np.concatenate([np.concatenate(road_map.lane_border_polylines(lane.key))
                               for lane in road_map.lane_list])
    return clutter_mod.clutter_mesh(road_map, lane_pts, [], np.random.default_rng([seed, 3]))


def _off_driving(road_map, pts, z_max):
    """Plan points of vertices lower than z_max: how far inside a driving lane (> 0 = in)."""
    low = pts[pts[:, 2] < z_max]
    pr = road_map.project(low[:, :2], LaneType.Driving)
    return pr.lane_width / 2 - np.abs(pr.lateral_m)


@pytest.fixture(scope="module")
def town01():
    return load_carla_map("Town01")[0]


def test_clutter_stays_off_the_driving_lanes(town01):
    """Every clutter vertex below 4.5 m (all but traffic-light arms and palm fronds) lies
    outside every driving lane, on the synthetic street and on Town01."""
    straight = RoadMap.from_string(STRAIGHT_XODR, name="straight")
    for m in (straight, town01):
        mesh = _clutter_only(m, 0)
        assert mesh.n_vertices > 1000
        inside = _off_driving(m, mesh.positions.astype(float), 4.5)
        assert inside.max() < 0.0, inside.max()


def test_clutter_has_every_kind_and_traffic_lights_reach_over_the_road(town01):
    mesh = _clutter_only(town01, 0)
    code = mesh.colors[:, 3].round().astype(int)
    for mat in (MAT_FOLIAGE, clutter_mod.MAT_ROCK, MAT_METAL, MAT_LAMP):
        assert (code == mat).sum() > 30, mat
    # lit signal lamps hang over the driving lanes, above the tallest vehicle
    lamps = mesh.positions[code == MAT_LAMP].astype(float)
    over = _off_driving(town01, lamps, 1e9) > 0
    assert over.sum() > 30
    assert lamps[over, 2].min() > 4.5
    # the scene's props hold the clutter (after the lamps and round trees of before)
    props = build_scene_meshes(town01, seed=0).props
    assert props.n_vertices > mesh.n_vertices


def test_clutter_is_deterministic_per_seed(straight_map):
    a = build_scene_meshes(straight_map, seed=4).props
    b = build_scene_meshes(straight_map, seed=4).props
    c = build_scene_meshes(straight_map, seed=5).props
    assert a.positions.tobytes() == b.positions.tobytes()
    assert a.colors.tobytes() == b.colors.tobytes()
    assert a.positions.tobytes() != c.positions.tobytes()


def test_clutter_is_never_labelled(gl_ctx, straight_map):
    """The same frames with and without clutter: silhouettes and projected boxes are
    equal, no pixel gets an id it did not have, and every vehicle pixel the clutter
    takes away is one where the clutter is nearer than the vehicle."""
    from dashtraj.render.scene import Renderer

    cam = (-95.0, -9.8, 1.6, 8.0, -2.0, 0.0)  # on the sidewalk's edge, looking along it
    models = [SEDAN, SUV, VAN, TRUCK, BUS, MOTO, BIKE]
    rng = np.random.default_rng(3)
    vs = [(i + 1, identity(models[i % 7], (120, 40, 40), i + 1), -88.0 + 6.0 * i,
           float(rng.choice([-5.25, -1.75, 1.75, 5.25])), 0.0, float(rng.uniform(0, 360)))
          for i in range(10)]
    with_c = Renderer(straight_map, 640, 360, 90.0, msaa=0, ctx=gl_ctx)
    try:
        f1 = with_c.render(cam, vs)
    finally:
        with_c.release()
    bare = Renderer(straight_map, 640, 360, 90.0, msaa=0, ctx=gl_ctx, clutter=False)
    try:
        f0 = bare.render(cam, vs)
    finally:
        bare.release()
    assert f1.rgb.tobytes() != f0.rgb.tobytes()  # the clutter is in view
    changed = f1.instance != f0.instance
    assert not (f1.instance[changed] != 0).any()  # clutter only ever hides vehicle pixels
    assert (f1.depth[changed] < f0.depth[changed]).all()
    for a, b in zip(f1.labels, f0.labels, strict=True):
        assert a.silhouette_box == b.silhouette_box
        assert a.projected_box == b.projected_box
        assert a.silhouette_pixels == b.silhouette_pixels
        assert a.visible_pixels <= b.visible_pixels


def test_contact_shadows_change_pixels_not_ids_or_depth(gl_ctx, straight_map):
    from dashtraj.render.scene import Renderer

    cam = (-95.0, 0.0, 1.6, 0.0, -5.0, 0.0)
    vs = [(1, identity(SEDAN, (200, 30, 30), 1), -85.0, -1.75, 0.0, 10.0),
          (2, identity(BUS, (30, 30, 200), 2), -75.0, 1.75, 0.0, 180.0),
          (3, identity(BIKE, (30, 200, 30), 3), -88.0, 5.25, 0.0, 90.0)]
    out = {}
    for msaa in (0, 4):
        r = Renderer(straight_map, 640, 360, 90.0, msaa=msaa, ctx=gl_ctx)
        try:
            for on in (True, False):
                r.contact_shadows = on
                out[msaa, on] = r.render(cam, vs)
        finally:
            r.release()
    for msaa in (0, 4):
        a, b = out[msaa, True], out[msaa, False]
        assert a.instance.tobytes() == b.instance.tobytes()
        assert a.depth.tobytes() == b.depth.tobytes()
        assert a.labels == b.labels
        # darker road just behind the sedan's tail (a patch of the ground under it)
        dark = a.rgb.astype(int).sum(axis=2) < b.rgb.astype(int).sum(axis=2) - 20
        assert dark.sum() > 100, dark.sum()
    assert out[0, True].instance.tobytes() == out[4, True].instance.tobytes()


def test_contact_shadow_lies_under_the_body_below_the_tyres():
    for model in (SEDAN, SUV, VAN, TRUCK, BUS, MOTO, BIKE):
        s = contact_shadow_mesh(model.length_m, model.width_m, model.body_type).positions
        v = vehicle_mesh(model, (10, 20, 30))
        assert np.abs(s[:, 0]).max() <= model.length_m / 2
        assert np.abs(s[:, 1]).max() <= model.width_m / 2
        assert s[:, 2].max() < v.positions[:, 2].min()  # never hides a tyre


def test_shadow_casters_are_the_body_without_its_details():
    """Every catalog vehicle's shadow caster stays inside its mesh's bounds (1 cm), keeps
    its length, width and height (the same body; tyres as boxes), and four-wheelers cast
    at most 60 % of their triangles."""
    for model in catalog_models():
        c = shadow_caster_mesh(model).positions
        p = vehicle_mesh(model, (10, 20, 30)).positions
        lo, hi = p.min(axis=0), p.max(axis=0)
        assert (c.min(axis=0) >= lo - 0.01).all() and (c.max(axis=0) <= hi + 0.01).all()
        assert np.allclose(c.max(axis=0) - c.min(axis=0), hi - lo, atol=0.04), model.blueprint_id
        if model.body_type not in ("motorcycle", "bicycle"):
            assert len(c) <= 0.6 * len(p), model.blueprint_id


def test_shadow_casters_change_pixels_only_slightly_never_labels(gl_ctx, straight_map,
                                                                  monkeypatch):
    """Drawing the full meshes into the shadow map instead of the casters leaves ids, depth
    and labels byte-identical and changes < 0.5 % of the pixels (shadow outlines)."""
    from dashtraj.render import meshes
    from dashtraj.render.scene import Renderer

    cam = (-95.0, 0.0, 1.6, 0.0, -5.0, 0.0)
    vs = [(1, identity(SEDAN, (200, 30, 30), 1), -85.0, -1.75, 0.0, 10.0),
          (2, identity(BUS, (30, 30, 200), 2), -75.0, 1.75, 0.0, 180.0),
          (3, identity(MOTO, (30, 200, 30), 3), -88.0, 5.25, 0.0, 90.0)]
    r = Renderer(straight_map, 640, 360, 90.0, msaa=0, ctx=gl_ctx)
    try:
        a = r.render(cam, vs)
        r2 = Renderer(straight_map, 640, 360, 90.0, msaa=0, ctx=gl_ctx)
        try:
            monkeypatch.setattr(meshes, "shadow_caster_mesh",
                                lambda model: vehicle_mesh(model, (0, 0, 0)))
            b = r2.render(cam, vs)
        finally:
            r2.release()
    finally:
        r.release()
    assert a.instance.tobytes() == b.instance.tobytes()
    assert a.depth.tobytes() == b.depth.tobytes()
    assert a.labels == b.labels
    changed = (a.rgb != b.rgb).any(axis=2).mean()
    assert changed < 0.005, changed


def test_every_catalog_vehicle_keeps_its_dimensions():
    for model in catalog_models():
        p = vehicle_mesh(model, (10, 20, 30)).positions
        assert p[:, 0].min() >= -model.length_m / 2 - 0.02, model.blueprint_id
        assert p[:, 0].max() <= model.length_m / 2 + 0.02, model.blueprint_id
        assert np.abs(p[:, 1]).max() <= max(model.width_m / 2, 0.26) + 0.02, model.blueprint_id
        assert p[:, 2].min() >= 0.0
        if model.body_type not in ("motorcycle", "bicycle"):  # riders stand above
            assert abs(p[:, 2].max() - model.height_m) < 0.02, model.blueprint_id


@pytest.mark.parametrize("model", [SEDAN, SUV, VAN, TRUCK, BUS], ids=lambda m: m.body_type)
def test_four_wheelers_have_glass_all_round_lamps_plates_and_wheel_arches(model):
    mesh = vehicle_mesh(model, (200, 10, 10))
    code = mesh.colors[:, 3].round().astype(int)
    n = mesh.normals[code == MAT_GLASS]
    for axis, sign in ((0, 1), (0, -1), (1, 1), (1, -1)):
        assert ((n[:, axis] * sign) > 0.5).sum() >= 6, (axis, sign)
    lamps = mesh.positions[code == MAT_LAMP]
    red = mesh.colors[code == MAT_LAMP][:, 0] - mesh.colors[code == MAT_LAMP][:, 1] > 0.5
    assert lamps[red, 0].max() < 0 < lamps[~red, 0].min()  # tail lamps back, head lamps front
    plate = np.abs(mesh.colors[:, :3] - np.array([0.88, 0.88, 0.84])).max(axis=1) < 1e-6
    assert (mesh.positions[plate, 0] > 0).any() and (mesh.positions[plate, 0] < 0).any()
    dark = (code == MAT_TYRE) & (mesh.colors[:, 0] < 0.03)  # arches
    assert dark.sum() >= 4 * 3 * 10
    rims = (code == MAT_METAL) & (mesh.colors[:, 0] > 0.5)
    assert rims.sum() >= 4 * 3 * 8


def test_rounded_car_is_not_a_box():
    """The body narrows and drops at the nose and the roof is narrower than the sills."""
    p = vehicle_mesh(SEDAN, (10, 20, 30)).positions
    body = p[(p[:, 2] > 0.3)]
    nose = body[body[:, 0] > SEDAN.length_m / 2 - 0.02]
    assert np.abs(nose[:, 1]).max() < np.abs(body[:, 1]).max() - 0.05
    roof = p[p[:, 2] > SEDAN.height_m - 0.05]
    assert np.abs(roof[:, 1]).max() < SEDAN.width_m / 2 - 0.1
    assert len(np.unique(p.round(3), axis=0)) > 200


def test_trims_tell_models_of_one_shape_apart():
    """The VW T2 and T2 2021 share every dimension; their trims (a white roof; dark rims,
    tinted glass and a tail light bar) make their meshes differ, and each feature is drawn
    where it belongs."""
    from dashtraj.render.vehicle_shapes import GLASS_TINTED, RIM_DARK, ROOF_COLORS
    from dashtraj.world.catalog import get_model

    t2, t2n = get_model("vehicle.volkswagen.t2"), get_model("vehicle.volkswagen.t2_2021")
    a, b = vehicle_mesh(t2, (118, 120, 124)), vehicle_mesh(t2n, (118, 120, 124))
    assert a.positions.shape != b.positions.shape or not np.array_equal(a.colors, b.colors)

    def has(mesh, rgb):
        return np.abs(mesh.colors[:, :3] - np.array(rgb)).max(axis=1) < 1e-6

    white = has(a, ROOF_COLORS["white"])  # the roof: on top, at the full height
    assert white.sum() >= 18 and a.positions[white, 2].min() > t2.height_m - 0.08
    assert not has(b, ROOF_COLORS["white"]).any()
    assert has(b, RIM_DARK).sum() >= 4 * 3 * 8 and not has(a, RIM_DARK).any()
    assert has(b, GLASS_TINTED).any() and not has(a, GLASS_TINTED).any()
    code = b.colors[:, 3].round().astype(int)
    red = (code == MAT_LAMP) & (b.colors[:, 0] - b.colors[:, 1] > 0.5)
    tri = b.positions[red].reshape(-1, 3, 3)  # the bar: one quad across the back
    assert (tri[:, :, 0] < 0).all() and tri[:, :, 1].min() < -0.5 < 0.5 < tri[:, :, 1].max()
    assert len(tri) == 2


def test_roof_rails_stay_inside_the_height_and_dark_roofs_replace_paint():
    from dashtraj.world.catalog import get_model

    rav4 = get_model("vehicle.toyota.rav4")  # rails
    p = vehicle_mesh(rav4, (190, 22, 30)).positions
    assert abs(p[:, 2].max() - rav4.height_m) < 0.005
    mini = get_model("vehicle.mini.cooper_s")  # black roof over red paint
    m = vehicle_mesh(mini, (190, 22, 30))
    red = np.abs(m.colors[:, :3] - np.array([190, 22, 30]) / 255).max(axis=1) < 1e-6
    top = m.positions.reshape(-1, 3, 3)[:, :, 2].min(axis=1) > mini.height_m - 0.02
    assert not (red.reshape(-1, 3).all(axis=1) & top).any()  # no paint on the roof
    black = np.abs(m.colors[:, :3] - np.array((0.02, 0.02, 0.022))).max(axis=1) < 1e-6
    assert (black.reshape(-1, 3).all(axis=1) & top).sum() >= 2  # the flat roof quad


def test_mesh_keys_are_the_trim_fields_and_cached_per_model():
    """``meshes._params`` (the mesh cache key, asked for every vehicle of every frame)
    carries each model's trim exactly as ``dataclasses.astuple`` would, and returns the
    same tuple for the same model object without recomputing it."""
    from dataclasses import astuple, replace

    from dashtraj.render.meshes import _params
    from dashtraj.world.catalog import Trim

    for m in catalog_models():
        p = _params(m)
        assert p[-1] == astuple(m.trim if m.trim is not None else Trim())
        assert _params(m) is p
    m = catalog_models()[0]
    other = replace(m, trim=Trim(roof="white", rims="dark"))
    assert _params(other)[-1] == astuple(other.trim) != _params(m)[-1]
