"""Domain randomization: random looks (weather, sun, scene colours, textures, camera)
drawn within stated ranges, for training sets that should transfer to other renderers
(CARLA's Unreal look becomes one more variation among many).

``random_look(rng)`` draws every field of :data:`RANGES` independently, uniform on
[lo, hi], except that a field with ``p_off > 0`` takes its ``off`` value (effect off)
with that probability; integer fields are rounded. Colour fields draw one grey level
g in [lo, hi] and give channel c the value g × hue_c plus a tint uniform in ±``tint``
(clipped to 0 … 1); ``facade_tint`` draws each channel in [lo, hi]. Everything else
keeps the default ``LookConfig()``'s value. The look's ``seed`` (sensor noise, rain
streaks) is drawn from the same generator, after every field but the two clutter tints
(added later, drawn last so the other fields of a seed's looks did not change).

The ranges (units as in ``dashtraj.render.look``; "off" = value and probability)::

    weather.cloudiness              0 … 100
    weather.precipitation           0 … 80      off 0 with p 0.75
    weather.precipitation_deposits  0 … 80      off 0 with p 0.6
    weather.wetness                 0 … 100     off 0 with p 0.5
    weather.fog_density             0 … 50      off 0 with p 0.6
    weather.fog_distance            0 … 40 m
    weather.sun_altitude_angle      5 … 90°
    weather.sun_azimuth_angle       0 … 360°
    camera.exposure_compensation    −1 … 1 EV
    camera.temp                     4500 … 8500 K
    camera.tint                     −0.3 … 0.3
    camera.gamma                    2.0 … 2.4
    camera.lens_circle_multiplier   0 … 1.5
    camera.lens_circle_falloff      3 … 6
    camera.blur_radius              0 … 1.2 px  off 0 with p 0.3
    camera.noise_stddev             0 … 5 levels
    camera.jpeg_quality             35 … 95     off 0 (no round trip) with p 0.3
    materials.asphalt_rgb           grey 0.12 … 0.45, tint ±0.015
    materials.sidewalk_rgb          grey 0.35 … 0.80, tint ±0.04
    materials.grass_rgb             grey 0.25 … 0.45 × hue (0.9, 1.15, 0.55), tint ±0.03
    materials.facade_tint           each channel 0.7 … 1.3
    materials.mark_wear             0 … 0.7
    materials.road_wear             0 … 1
    materials.texture_scale         0.6 … 1.8
    materials.texture_offset        each 0 … 1000 m
    materials.foliage_tint          each channel 0.7 … 1.3 (trees, bushes, hedges)
    materials.prop_tint             each channel 0.6 … 1.4 (clutter: lights, rocks, walls …)

``violations(look)`` lists the fields of a look outside these ranges (empty for every
drawn look; the tests check it on many seeds).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from dashtraj.render.look import LookConfig


@dataclass(frozen=True)
class Range:
    """One randomized field: ``path`` = "group.field" of ``LookConfig``; uniform on
    [lo, hi]; ``off`` with probability ``p_off``; ``kind`` "float", "int", "colour"
    (grey in [lo, hi] + per-channel ±tint), "channels" (each channel in [lo, hi]) or
    "pair" (two values in [lo, hi])."""

    path: str
    lo: float
    hi: float
    p_off: float = 0.0
    off: float = 0.0
    kind: str = "float"
    tint: float = 0.0
    hue: tuple[float, float, float] = (1.0, 1.0, 1.0)


RANGES: tuple[Range, ...] = (
    Range("weather.cloudiness", 0.0, 100.0),
    Range("weather.precipitation", 0.0, 80.0, p_off=0.75),
    Range("weather.precipitation_deposits", 0.0, 80.0, p_off=0.6),
    Range("weather.wetness", 0.0, 100.0, p_off=0.5),
    Range("weather.fog_density", 0.0, 50.0, p_off=0.6),
    Range("weather.fog_distance", 0.0, 40.0),
    Range("weather.sun_altitude_angle", 5.0, 90.0),
    Range("weather.sun_azimuth_angle", 0.0, 360.0),
    Range("camera.exposure_compensation", -1.0, 1.0),
    Range("camera.temp", 4500.0, 8500.0),
    Range("camera.tint", -0.3, 0.3),
    Range("camera.gamma", 2.0, 2.4),
    Range("camera.lens_circle_multiplier", 0.0, 1.5),
    Range("camera.lens_circle_falloff", 3.0, 6.0),
    Range("camera.blur_radius", 0.0, 1.2, p_off=0.3),
    Range("camera.noise_stddev", 0.0, 5.0),
    Range("camera.jpeg_quality", 35, 95, p_off=0.3, kind="int"),
    Range("materials.asphalt_rgb", 0.12, 0.45, kind="colour", tint=0.015),
    Range("materials.sidewalk_rgb", 0.35, 0.80, kind="colour", tint=0.04),
    Range("materials.grass_rgb", 0.25, 0.45, kind="colour", tint=0.03, hue=(0.9, 1.15, 0.55)),
    Range("materials.facade_tint", 0.7, 1.3, kind="channels"),
    Range("materials.mark_wear", 0.0, 0.7),
    Range("materials.road_wear", 0.0, 1.0),
    Range("materials.texture_scale", 0.6, 1.8),
    Range("materials.texture_offset", 0.0, 1000.0, kind="pair"),
)
_LATE = (  # drawn after the look's seed: the earlier fields' stream stays as it was
    Range("materials.foliage_tint", 0.7, 1.3, kind="channels"),
    Range("materials.prop_tint", 0.6, 1.4, kind="channels"),
)
_EARLY = RANGES
RANGES = _EARLY + _LATE
"""The randomized fields and their ranges (module docstring)."""

CAMERA_PATHS = tuple(r.path for r in RANGES if r.path.startswith("camera."))
"""The camera-effect fields (the ReID set draws them per camera, the rest per identity)."""


def _draw(r: Range, rng: np.random.Generator):
    u = rng.uniform()  # always drawn: the stream does not depend on which branch is taken
    if r.kind == "colour":
        grey = rng.uniform(r.lo, r.hi)
        t = rng.uniform(-r.tint, r.tint, 3)
        return tuple(float(np.clip(grey * h + x, 0.0, 1.0)) for h, x in zip(r.hue, t, strict=True))
    if r.kind == "channels":
        return tuple(float(x) for x in rng.uniform(r.lo, r.hi, 3))
    if r.kind == "pair":
        return tuple(float(x) for x in rng.uniform(r.lo, r.hi, 2))
    v = rng.uniform(r.lo, r.hi)
    if u < r.p_off:
        v = r.off
    return round(v) if r.kind == "int" else float(v)


def random_look(rng: np.random.Generator, base: LookConfig | None = None,
                paths: tuple[str, ...] | None = None) -> LookConfig:
    """A look with the fields of :data:`RANGES` (or only ``paths``) drawn from ``rng``;
    the other fields as in ``base`` (default ``LookConfig()``). Deterministic for the
    generator's state."""
    look = base if base is not None else LookConfig()
    groups = {"weather": {}, "camera": {}, "materials": {}}

    def draw(ranges):
        for r in ranges:
            value = _draw(r, rng)  # drawn even when not applied: same stream for every subset
            if paths is None or r.path in paths:
                g, name = r.path.split(".")
                groups[g][name] = value

    draw(_EARLY)
    seed = int(rng.integers(2**31))
    draw(_LATE)
    return replace(
        look,
        weather=replace(look.weather, **groups["weather"]),
        camera=replace(look.camera, **groups["camera"]),
        materials=replace(look.materials, **groups["materials"]),
        seed=seed if paths is None or "seed" in paths else look.seed,
    )


def violations(look: LookConfig) -> list[str]:
    """The randomized fields of ``look`` outside their :data:`RANGES` (empty if none)."""
    out = []
    for r in RANGES:
        g, name = r.path.split(".")
        v = getattr(getattr(look, g), name)
        vals = np.atleast_1d(np.asarray(v, float))
        if r.kind == "colour":
            # some grey g in [lo, hi] with |value_c - g * hue_c| <= tint (before clipping)
            hue = np.array(r.hue)
            lo_g = np.max((vals - r.tint) / hue)
            hi_g = np.min((vals + r.tint) / hue)
            clipped = (vals <= 0.0) | (vals >= 1.0)
            ok = bool(((vals >= 0) & (vals <= 1)).all()) and (
                clipped.any() or (max(lo_g, r.lo) <= min(hi_g, r.hi) + 1e-9))
        else:
            inside = (vals >= r.lo - 1e-12) & (vals <= r.hi + 1e-12)
            ok = bool(inside.all()) or (r.p_off > 0 and bool((vals == r.off).all()))
        if r.kind == "int" and not float(vals[0]).is_integer():
            ok = False
        if not ok:
            out.append(f"{r.path} = {v!r} outside [{r.lo}, {r.hi}]")
    return out


def describe() -> list[dict]:
    """The ranges as JSON-ready dicts (for ``dataset.json`` / ``reid.json``)."""
    out = []
    for r in RANGES:
        d = {"field": r.path, "lo": r.lo, "hi": r.hi, "kind": r.kind}
        if r.p_off:
            d.update(p_off=r.p_off, off=r.off)
        if r.kind == "colour":
            d.update(tint=r.tint, hue=list(r.hue))
        out.append(d)
    return out


def frame_rng(seed: int, *keys: int) -> np.random.Generator:
    """The generator of one frame or identity: ``default_rng([seed, *keys])`` (so a
    frame's look does not depend on the order frames are rendered in)."""
    return np.random.default_rng([int(seed), *(int(k) for k in keys)])
