"""The look (weather, materials, camera effects): pixels change, labels never do; same
look, same bytes; shadows fall away from the sun; looks round-trip through JSON.

Scene: the synthetic straight road of ``render_scene`` (tests/render/conftest.py)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from dashtraj.render.look import (
    PRESETS,
    CameraLook,
    LookConfig,
    LookError,
    UnknownPresetError,
    Weather,
    lighting,
    preset,
    sun_direction,
    with_weather,
)
from dashtraj.render.scene import Renderer, project_points
from render_scene import BUS, MOTO, SEDAN, SUV, TRUCK, identity

CAM = (-95.0, 1.75, 1.6, 0.0, 0.0, 0.0)
VEHICLES = [
    (1, identity(SEDAN, (180, 20, 20)), -85.0, 1.75, 0.0, 0.0),
    (2, identity(SUV, (30, 30, 35), 2), -80.0, -1.75, 0.0, 180.0),
    (3, identity(TRUCK, (200, 180, 40), 3), -60.0, 5.25, 0.0, 0.0),
    (4, identity(BUS, (20, 60, 160), 4), -70.0, -5.25, 0.0, 180.0),
    (5, identity(MOTO, (40, 40, 40), 5), -88.0, -1.75, 0.0, 170.0),
    (6, identity(SEDAN, (240, 240, 240), 6), -78.0, 1.75, 0.0, 0.0),  # partly behind 1
]


@pytest.fixture(scope="module", params=[0, 4], ids=["one-pass", "msaa"])
def renderer(request, gl_ctx, straight_map):
    r = Renderer(straight_map, 320, 180, 90.0, msaa=request.param, ctx=gl_ctx)
    yield r
    r.release()


def _render(r, look, pose=CAM, vehicles=VEHICLES):
    r.set_look(look)
    return r.render(pose, vehicles)


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_looks_change_pixels_never_labels(renderer, name):
    ref = _render(renderer, LookConfig())
    f = _render(renderer, preset(name))
    assert np.array_equal(f.instance, ref.instance)
    assert np.array_equal(f.depth, ref.depth)
    assert f.labels == ref.labels
    assert sum(lb.in_view for lb in f.labels) >= 4
    if name != "clear":
        diff = np.abs(f.rgb.astype(int) - ref.rgb.astype(int)).mean()
        assert diff > 2.0, f"{name}: mean |Δ| {diff:.2f} levels"


def test_each_weather_parameter_changes_pixels(renderer):
    base = with_weather(LookConfig(), sun_altitude_angle=40.0)
    ref = _render(renderer, base)
    changes = {
        "cloudiness": 80.0, "precipitation": 60.0, "precipitation_deposits": 80.0,
        "wetness": 80.0, "fog_density": 50.0, "sun_altitude_angle": 10.0,
        "sun_azimuth_angle": 300.0,
    }
    for name, value in changes.items():
        f = _render(renderer, with_weather(base, **name_value(name, value)))
        assert f.labels == ref.labels and np.array_equal(f.instance, ref.instance)
        assert not np.array_equal(f.rgb, ref.rgb), name
    for field_, value in (("exposure_compensation", 1.0), ("temp", 4500.0), ("tint", 0.5),
                          ("gamma", 1.8), ("lens_circle_multiplier", 2.0), ("blur_radius", 1.0),
                          ("noise_stddev", 6.0), ("jpeg_quality", 30)):
        look = replace(base, camera=replace(base.camera, **{field_: value}))
        f = _render(renderer, look)
        assert f.labels == ref.labels and np.array_equal(f.instance, ref.instance)
        assert not np.array_equal(f.rgb, ref.rgb), field_


def name_value(name, value):
    return {name: value}


def test_same_look_same_bytes(gl_ctx, straight_map):
    look = replace(preset("rain"), camera=CameraLook(noise_stddev=4.0, blur_radius=0.8,
                                                     jpeg_quality=60), seed=3)
    out = []
    for _ in range(2):
        r = Renderer(straight_map, 320, 180, 90.0, msaa=0, ctx=gl_ctx, look=look)
        out.append(r.render(CAM, VEHICLES).rgb.tobytes())
        r.release()
    assert out[0] == out[1]
    # the noise and the rain follow the seed: another seed, other bytes, same labels
    r = Renderer(straight_map, 320, 180, 90.0, msaa=0, ctx=gl_ctx, look=replace(look, seed=4))
    assert r.render(CAM, VEHICLES).rgb.tobytes() != out[0]
    r.release()


@pytest.mark.parametrize("azimuth", [0.0, 90.0, 180.0, 270.0, 45.0])
def test_shadows_fall_away_from_the_sun(gl_ctx, straight_map, azimuth):
    """A bus on the road seen from straight above: the ground beside it on the side away
    from the sun is darker with shadows than without; the sunny side is not."""
    r = Renderer(straight_map, 320, 320, 90.0, msaa=0, ctx=gl_ctx)
    bus = [(1, identity(BUS, (200, 200, 200)), -50.0, 0.0, 0.0, 0.0)]
    pose = (-50.0, 0.0, 40.0, 0.0, -90.0, 0.0)
    look = with_weather(LookConfig(), sun_altitude_angle=45.0, sun_azimuth_angle=azimuth,
                        cloudiness=0.0)
    look = replace(look, camera=replace(look.camera, noise_stddev=0.0))
    lit = _render(r, look, pose, bus)
    flat = _render(r, replace(look, materials=replace(look.materials, shadows=False)), pose, bus)
    r.release()
    a = math.radians(azimuth)
    # where the ray from the bus centre along the azimuth leaves its footprint (12 x 2.55 m,
    # 3.2 m high), then 1.8 m further: inside its 3.2 m long shadow at 45° altitude
    c, s_ = abs(math.cos(a)), abs(math.sin(a))
    reach = min(6.0 / c if c > 1e-9 else math.inf, 1.275 / s_ if s_ > 1e-9 else math.inf) + 1.8
    sides = {}
    for side, sign in (("sunny", 1.0), ("shadow", -1.0)):
        p = np.array([[-50.0 + sign * reach * math.cos(a), sign * reach * math.sin(a), 0.0]])
        (u, v), = project_points(p, pose, r.k)[0]
        i, j = int(v), int(u)
        win = (slice(i - 3, i + 4), slice(j - 3, j + 4))
        assert (lit.instance[win] == 0).all()
        ratio = lit.rgb[win].astype(float).mean() / flat.rgb[win].astype(float).mean()
        sides[side] = ratio
    assert sides["shadow"] < 0.8, sides
    assert sides["sunny"] > 0.97, sides


def test_sun_direction_and_lighting():
    d = sun_direction(Weather(sun_altitude_angle=30.0, sun_azimuth_angle=90.0))
    np.testing.assert_allclose(d, [0.0, math.cos(math.radians(30)), 0.5], atol=1e-12)
    clear, dusk, cloudy = (lighting(preset(n)) for n in ("clear", "dusk", "overcast"))
    assert dusk.sun_rgb[2] / dusk.sun_rgb[0] < clear.sun_rgb[2] / clear.sun_rgb[0]  # redder
    assert cloudy.shadow_strength < 0.2 < clear.shadow_strength
    assert lighting(preset("fog")).fog_sigma > 10 * clear.fog_sigma
    night = lighting(with_weather(LookConfig(), sun_altitude_angle=-30.0))
    assert night.sun_rgb.max() == 0.0
    warm = lighting(replace(LookConfig(), camera=CameraLook(temp=4000.0))).white_balance
    assert warm[2] > warm[0]  # a lower white-balance temperature renders bluer


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_looks_round_trip_through_json(name):
    look = replace(preset(name), seed=11)
    assert LookConfig.from_json(look.to_json()) == look
    assert LookConfig.from_dict(look.to_dict()) == look


def test_bad_look_names_and_fields():
    with pytest.raises(UnknownPresetError, match=r"clear.*dusk.*fog"):
        preset("sunny")
    with pytest.raises(LookError, match=r"weather.*rain"):
        LookConfig.from_dict({"weather": {"rain": 3}})
    with pytest.raises(TypeError):
        Renderer.set_look(object(), "clear")


def test_renderers_sharing_a_context_keep_their_own_looks(gl_ctx, straight_map):
    """Shader variants are shared per context; each renderer's look must still be its own."""
    looks = (preset("dusk"), preset("fog"))
    solo = []
    for look in looks:
        r = Renderer(straight_map, 160, 90, 90.0, msaa=0, ctx=gl_ctx, look=look)
        solo.append(r.render(CAM, VEHICLES).rgb)
        r.release()
    a = Renderer(straight_map, 160, 90, 90.0, msaa=0, ctx=gl_ctx, look=looks[0])
    b = Renderer(straight_map, 160, 90, 90.0, msaa=0, ctx=gl_ctx, look=looks[1])
    for _ in range(2):
        assert np.array_equal(a.render(CAM, VEHICLES).rgb, solo[0])
        assert np.array_equal(b.render(CAM, VEHICLES).rgb, solo[1])
    b.set_look(looks[0])
    assert np.array_equal(b.render(CAM, VEHICLES).rgb, solo[0])
    a.release()
    b.release()


@pytest.mark.parametrize("sigma", [0.4, 0.7, 1.0, 1.3])
def test_blur_has_the_requested_sigma(sigma):
    from dashtraj.render.post import blur

    img = np.zeros((41, 41, 3), np.uint8)
    img[20, 20] = 255
    b = blur(img, sigma)[:, :, 0].astype(float)
    b /= b.sum()
    y, x = np.mgrid[:41, :41]
    tol = 0.08 if sigma < 1.1 else 0.12  # 8-bit rounding trims the tails of wide kernels
    assert abs(math.sqrt((b * (x - 20) ** 2).sum()) - sigma) < tol
    assert abs(math.sqrt((b * (y - 20) ** 2).sum()) - sigma) < tol
    flat = np.full((9, 9, 3), 77, np.uint8)
    assert (blur(flat, sigma) == 77).all()


def test_vignette_polynomial_follows_carla_lens_circle():
    """The shader's vignetting polynomial (``vignette_fit``) stays within 0.6 levels of
    1 / (1 + multiplier · r^falloff) over the randomized ranges at 16:9 and 4:3, and is
    exactly 1 without vignetting."""
    from dashtraj.render.scene import vignette_fit

    for aspect in (360 / 640, 3 / 4):
        r2_max = 1.0 + aspect**2
        s = np.linspace(0.0, r2_max, 2001).astype(np.float32)
        for m in (0.0, 0.35, 0.8, 1.5):
            for f in (3.0, 4.2, 5.0, 6.0):
                a = np.array(vignette_fit(m, f, r2_max), np.float32)
                got = np.full_like(s, a[-1])
                for c in a[-2::-1]:  # Horner, in float32 like the shader
                    got = got * s + c
                want = 1.0 / (1.0 + m * s.astype(np.float64) ** (f / 2))
                assert np.abs(got - want).max() * 255 < 0.6, (aspect, m, f)
    assert vignette_fit(0.0, 5.0, 1.3) == (1.0,) + (0.0,) * 7


def _noise_reference(size: int, seed: int) -> np.ndarray:
    """The noise texture as first written: complex FFTs, ranks by a stable argsort."""
    rng = np.random.default_rng(seed)
    f = np.fft.fftfreq(size)
    r = np.hypot(f[:, None], f[None, :])
    out = np.empty((size, size, 4), np.uint8)
    filters = (np.exp(-((r / 0.25) ** 2)), np.exp(-((r / 0.005) ** 2)),
               np.exp(-((r / 0.02) ** 2)),
               np.where(r > 0, 1.0 / np.maximum(r, 1.0 / size) ** 1.6, 0.0))
    for c, filt in enumerate(filters):
        x = np.real(np.fft.ifft2(np.fft.fft2(rng.standard_normal((size, size))) * filt))
        rank = np.empty(x.size, np.int64)
        rank[np.argsort(x, axis=None, kind="stable")] = np.arange(x.size)
        out[:, :, c] = (rank * 256 // rank.size).reshape(size, size).astype(np.uint8)
    return out


@pytest.mark.parametrize(("size", "seed"), [(64, 7), (128, 3), (256, 7)])
def test_noise_texture_equals_argsort_ranks_and_is_uniform(size, seed):
    from dashtraj.render.scene import build_noise_texture

    got = build_noise_texture(size, seed)
    np.testing.assert_array_equal(got, _noise_reference(size, seed))
    for c in range(4):  # rank-equalised: every level holds size² / 256 texels
        np.testing.assert_array_equal(np.bincount(got[..., c].ravel(), minlength=256),
                                      np.full(256, size * size // 256))


def test_noise_texture_is_kept_as_a_file_and_read_back(tmp_path, monkeypatch):
    """The noise texture goes to the cache folder once; a process that has it not in memory
    reads it (the same bytes, never built), and a file that is not whole is built again."""
    from dashtraj.render import scene

    monkeypatch.setenv("DASHTRAJ_CACHE", str(tmp_path))
    want = scene.build_noise_texture(64, 3)
    scene.noise_texture.cache_clear()
    try:
        got = scene.noise_texture(64, 3)
        (path,) = (tmp_path / "textures").glob("noise-*.npy")
        np.testing.assert_array_equal(got, want)
        assert not got.flags.writeable and not list(path.parent.glob(".*.tmp"))
        scene.noise_texture.cache_clear()
        monkeypatch.setattr(scene, "build_noise_texture", lambda *a: pytest.fail("built"))
        np.testing.assert_array_equal(scene.noise_texture(64, 3), want)
        monkeypatch.undo()
        monkeypatch.setenv("DASHTRAJ_CACHE", str(tmp_path))
        path.write_bytes(path.read_bytes()[:500])
        scene.noise_texture.cache_clear()
        np.testing.assert_array_equal(scene.noise_texture(64, 3), want)
        np.testing.assert_array_equal(np.load(path), want)  # written whole again
    finally:
        scene.noise_texture.cache_clear()
