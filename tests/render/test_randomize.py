"""Domain randomization: every drawn look lies within the stated ranges, the ranges are
really used, the draws are seeded, and the range check catches values outside."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from dashtraj.render.look import LookConfig
from dashtraj.render.randomize import (
    CAMERA_PATHS,
    RANGES,
    describe,
    frame_rng,
    random_look,
    violations,
)


def _value(look, path):
    g, name = path.split(".")
    return getattr(getattr(look, g), name)


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(0, 10**6), st.integers(0, 10**6))
def test_every_draw_respects_every_range(seed, a, b):
    look = random_look(frame_rng(seed, a, b))
    assert violations(look) == []
    assert LookConfig.from_json(look.to_json()) == look
    for r in RANGES:
        v = np.atleast_1d(np.asarray(_value(look, r.path), float))
        if r.kind == "colour":
            assert ((v >= 0) & (v <= 1)).all()
        elif not (r.p_off and (v == r.off).all()):
            assert ((v >= r.lo) & (v <= r.hi)).all(), (r.path, v)


def test_draws_cover_their_ranges_and_switch_effects_off():
    looks = [random_look(np.random.default_rng(i)) for i in range(600)]
    for r in RANGES:
        v = np.array([np.ravel(np.asarray(_value(lk, r.path), float)) for lk in looks])
        if r.kind == "colour":
            continue
        on = v[~(v == r.off).all(axis=1)] if r.p_off else v
        span = r.hi - r.lo
        assert on.min() < r.lo + 0.1 * span and on.max() > r.hi - 0.1 * span, r.path
        if r.p_off:
            share = 1.0 - len(on) / len(v)
            assert abs(share - r.p_off) < 0.08, (r.path, share)
    grey = np.array([np.mean(lk.materials.asphalt_rgb) for lk in looks])
    assert grey.min() < 0.16 and grey.max() > 0.41


def test_violations_name_the_field():
    look = random_look(np.random.default_rng(1))
    bad = replace(look, weather=replace(look.weather, sun_altitude_angle=-10.0))
    assert violations(bad) == ["weather.sun_altitude_angle = -10.0 outside [5.0, 90.0]"]
    bad = replace(look, materials=replace(look.materials, asphalt_rgb=(0.9, 0.1, 0.1)))
    assert [v.split(" =")[0] for v in violations(bad)] == ["materials.asphalt_rgb"]
    bad = replace(look, camera=replace(look.camera, jpeg_quality=20))
    assert [v.split(" =")[0] for v in violations(bad)] == ["camera.jpeg_quality"]


def test_seeded_and_subsets():
    a = random_look(frame_rng(3, 1, 2))
    assert a == random_look(frame_rng(3, 1, 2))
    assert a != random_look(frame_rng(3, 1, 3))
    base = random_look(frame_rng(9))
    cam = random_look(frame_rng(9, 4), base=base, paths=CAMERA_PATHS)
    assert cam.weather == base.weather and cam.materials == base.materials
    assert cam.camera != base.camera and cam.seed == base.seed
    assert [d["field"] for d in describe()] == [r.path for r in RANGES]
