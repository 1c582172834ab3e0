"""The look of a rendered frame: weather, materials and camera, in CARLA's vocabulary.

A :class:`LookConfig` is one frozen record of everything that changes pixels but never
labels (labels come from the renderer's id pass, never from the shaded image):

- :class:`Weather`: the fields of CARLA's ``carla.WeatherParameters`` that the renderer
  draws, with CARLA's names, units and ranges: ``cloudiness``, ``precipitation``,
  ``precipitation_deposits``, ``wetness``, ``fog_density`` (0–100 each), ``fog_distance``
  (m), ``sun_altitude_angle`` (−90…90°), ``sun_azimuth_angle`` (0…360°).
- :class:`CameraLook`: post-processing of the RGB camera, with the attribute names of
  CARLA's ``sensor.camera.rgb`` where CARLA has one (``exposure_compensation`` in EV,
  ``temp`` white balance in K, ``tint``, ``lens_circle_multiplier`` and
  ``lens_circle_falloff`` for vignetting, ``blur_radius``, ``gamma``) and dashtraj's own
  where it has none (``noise_stddev`` in 8-bit levels, ``jpeg_quality``).
- :class:`Materials`: colours and texture settings of the static scene (asphalt,
  sidewalk, grass, facades, lane-mark wear, texture scale and offset).

Frames and units: the sun direction is in the CARLA world frame (x, y, z; z up). The
azimuth is measured like CARLA's yaw, degrees from +x toward +y; ``sun_direction``
returns the unit vector *toward* the sun. The renderer's lighting is derived from a
look by :func:`lighting` (pure numpy, no GL), so it can be tested on its own.

Presets (``PRESETS``; ``preset(name)`` raises ``UnknownPresetError`` listing them):
``clear`` (the default: clear mid-morning), ``overcast``, ``fog``, ``wet``, ``dusk``,
``rain`` and ``flat`` (the renderer's look before shading existed: fixed sun, flat
sky, no textures, shadows or camera effects; for before/after pictures).

Every record round-trips through JSON: ``LookConfig.from_dict(look.to_dict()) == look``.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, fields, replace

import numpy as np

from dashtraj.errors import DashtrajError


class UnknownPresetError(DashtrajError):
    """A look preset name that is not in ``PRESETS``; the message lists the valid names."""


class LookError(DashtrajError):
    """A look value is outside its documented range; the message names the field."""


@dataclass(frozen=True)
class Weather:
    """CARLA ``WeatherParameters`` fields the renderer draws (CARLA names and units).

    Attributes:
        cloudiness: 0 clear sky … 100 fully overcast (dims and softens the sun, greys
            the sky, draws clouds).
        precipitation: 0 none … 100 heavy rain (rain streaks in the image, darker light).
        precipitation_deposits: 0 … 100, puddles on the road (mirror-like patches).
        wetness: 0 … 100, wet road (darker asphalt, sky reflected in it).
        fog_density: 0 … 100; 100 = extinction 0.08 / m (≈ 40 m visibility).
        fog_distance: metres from the camera where the fog starts.
        sun_altitude_angle: degrees above the horizon (−90 … 90; below 0 = night:
            no sun, dim sky).
        sun_azimuth_angle: degrees, CARLA yaw sense (from +x toward +y), 0 … 360.
    """

    cloudiness: float = 0.0
    precipitation: float = 0.0
    precipitation_deposits: float = 0.0
    wetness: float = 0.0
    fog_density: float = 0.0
    fog_distance: float = 0.0
    sun_altitude_angle: float = 50.0
    sun_azimuth_angle: float = 140.0


@dataclass(frozen=True)
class CameraLook:
    """Camera post-processing; CARLA ``sensor.camera.rgb`` attribute names where they exist.

    Attributes:
        exposure_compensation: EV stops (CARLA: ``exposure_compensation``); +1 doubles
            the light.
        temp: white balance temperature, K (CARLA: ``temp``, default 6500): the scene
            is lit by 6500 K light, so lower values render bluer, higher warmer.
        tint: green–magenta white-balance shift (CARLA: ``tint``, −1 … 1).
        gamma: display gamma (CARLA: ``gamma``, 2.2).
        lens_circle_multiplier: vignetting strength (CARLA: same name; 0 = none).
        lens_circle_falloff: vignetting falloff exponent (CARLA: same name, 5.0).
        blur_radius: Gaussian blur sigma in pixels at 640 px width, scaled with the
            image width (CARLA: ``blur_radius``, there for motion blur; 0 = none).
        noise_stddev: sensor noise, standard deviation in 8-bit levels (0 = none).
        jpeg_quality: JPEG round trip at this quality (1 … 100) applied to the image,
            or 0 for none.
    """

    exposure_compensation: float = 0.0
    temp: float = 6500.0
    tint: float = 0.0
    gamma: float = 2.2
    lens_circle_multiplier: float = 0.35
    lens_circle_falloff: float = 5.0
    blur_radius: float = 0.0
    noise_stddev: float = 1.5
    jpeg_quality: int = 0


@dataclass(frozen=True)
class Materials:
    """Colours (sRGB, 0 … 1) and textures of the static scene.

    Attributes:
        asphalt_rgb, sidewalk_rgb, grass_rgb: base colours of the surfaces.
        facade_tint: multiplies every facade's own colour (per channel).
        foliage_tint, prop_tint: multiply the colours of the roadside foliage (trees,
            bushes, hedges) and of the other props and clutter (``dashtraj.render.clutter``).
        mark_wear: 0 … 1, share of the lane marks' paint worn away.
        road_wear: 0 … 1, strength of patches and stains on the asphalt.
        texture_scale: world size multiplier of every procedural texture (1 = nominal).
        texture_offset: (u, v) offset of the texture coordinates, metres (a different
            offset gives a different pattern of the same statistics).
        shadows: draw sun shadows (shadow map).
        textures: draw procedural textures, windows and reflections (False = flat
            colours with Lambert shading only).
    """

    asphalt_rgb: tuple[float, float, float] = (0.30, 0.30, 0.31)
    sidewalk_rgb: tuple[float, float, float] = (0.62, 0.61, 0.58)
    grass_rgb: tuple[float, float, float] = (0.30, 0.38, 0.20)
    facade_tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    foliage_tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    prop_tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    mark_wear: float = 0.2
    road_wear: float = 0.3
    texture_scale: float = 1.0
    texture_offset: tuple[float, float] = (0.0, 0.0)
    shadows: bool = True
    textures: bool = True


@dataclass(frozen=True)
class LookConfig:
    """Everything that changes pixels but not labels. ``seed`` varies the sensor noise and
    rain streaks (with the camera pose, so every frame differs but repeats exactly)."""

    weather: Weather = field(default_factory=Weather)
    camera: CameraLook = field(default_factory=CameraLook)
    materials: Materials = field(default_factory=Materials)
    legacy: bool = False
    seed: int = 0

    # ------------------------------------------------------------------ JSON
    def to_dict(self) -> dict:
        """Nested plain dict (tuples as lists), JSON-serialisable."""
        return json.loads(json.dumps(asdict(self)))

    @classmethod
    def from_dict(cls, d: dict) -> LookConfig:
        """Inverse of :meth:`to_dict`; unknown keys raise ``LookError`` naming them."""
        def build(kind, data, where):
            if not isinstance(data, dict):
                raise LookError(f"look {where}: expected an object, got {data!r}")
            names = {f.name: f for f in fields(kind)}
            bad = sorted(set(data) - set(names))
            if bad:
                raise LookError(f"look {where}: unknown field(s) {bad}; valid: {sorted(names)}")
            out = {}
            for k, v in data.items():
                if isinstance(v, list):
                    v = tuple(v)
                out[k] = v
            return kind(**out)

        d = dict(d)
        sub = {}
        for name, kind in (("weather", Weather), ("camera", CameraLook), ("materials", Materials)):
            if name in d:
                sub[name] = build(kind, d.pop(name), name)
        top = build(_Top, d, "")
        return cls(**sub, legacy=bool(top.legacy), seed=int(top.seed))

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> LookConfig:
        return cls.from_dict(json.loads(text))

    def flat(self, prefix: str = "look_") -> dict:
        """One-level dict ``{look_weather_cloudiness: …, look_materials_asphalt_rgb_0: …}``
        of numbers (for table columns)."""
        out = {}
        for group, rec in (("weather", self.weather), ("camera", self.camera),
                           ("materials", self.materials)):
            for k, v in asdict(rec).items():
                if isinstance(v, tuple | list):
                    for i, x in enumerate(v):
                        out[f"{prefix}{group}_{k}_{i}"] = float(x)
                elif isinstance(v, bool):
                    out[f"{prefix}{group}_{k}"] = bool(v)
                else:
                    out[f"{prefix}{group}_{k}"] = float(v)
        out[f"{prefix}seed"] = int(self.seed)
        return out


@dataclass(frozen=True)
class _Top:
    legacy: bool = False
    seed: int = 0


# ---------------------------------------------------------------------- presets
PRESETS: dict[str, LookConfig] = {
    "clear": LookConfig(),
    "overcast": LookConfig(weather=Weather(cloudiness=90.0, sun_altitude_angle=45.0)),
    "fog": LookConfig(weather=Weather(cloudiness=60.0, fog_density=45.0, fog_distance=5.0,
                                      sun_altitude_angle=35.0)),
    "wet": LookConfig(weather=Weather(cloudiness=70.0, wetness=90.0, precipitation_deposits=50.0,
                                      sun_altitude_angle=40.0)),
    "rain": LookConfig(weather=Weather(cloudiness=95.0, precipitation=60.0, wetness=100.0,
                                       precipitation_deposits=70.0, fog_density=10.0,
                                       sun_altitude_angle=40.0)),
    "dusk": LookConfig(weather=Weather(cloudiness=20.0, sun_altitude_angle=6.0,
                                       sun_azimuth_angle=200.0)),
    "flat": LookConfig(legacy=True, camera=CameraLook(lens_circle_multiplier=0.0,
                                                      noise_stddev=0.0),
                       materials=Materials(shadows=False, textures=False)),
}
"""Looks by name. CARLA's own presets map roughly as ClearNoon → clear, CloudyNoon →
overcast, WetCloudyNoon → wet, MidRainyNoon → rain, ClearSunset → dusk."""


def preset(name: str) -> LookConfig:
    """The preset look ``name``; ``UnknownPresetError`` lists the valid names."""
    try:
        return PRESETS[name]
    except KeyError:
        raise UnknownPresetError(
            f"unknown look preset {name!r}; valid: {', '.join(sorted(PRESETS))}"
        ) from None


# ---------------------------------------------------------------------- lighting
def sun_direction(weather: Weather) -> np.ndarray:
    """(3,) unit vector toward the sun, CARLA world frame (x, y, z; z up)."""
    alt = math.radians(weather.sun_altitude_angle)
    az = math.radians(weather.sun_azimuth_angle)
    return np.array([math.cos(alt) * math.cos(az), math.cos(alt) * math.sin(az), math.sin(alt)])


def _kelvin_rgb(temp_k: float) -> np.ndarray:
    """Approximate linear RGB of a black body at ``temp_k`` (Tanner Helland's fit),
    normalised so that 6500 K is (1, 1, 1)."""
    def fit(t):
        t = t / 100.0
        r = 255.0 if t <= 66 else 329.698727446 * (t - 60) ** -0.1332047592
        g = 99.4708025861 * math.log(t) - 161.1195681661 if t <= 66 else \
            288.1221695283 * (t - 60) ** -0.0755148492
        b = 255.0 if t >= 66 else (0.0 if t <= 19 else 138.5177312231 * math.log(t - 10)
                                   - 305.0447927307)
        return np.clip(np.array([r, g, b]) / 255.0, 1e-3, 1.0) ** 2.2

    return fit(float(temp_k)) / fit(6500.0)


@dataclass(frozen=True)
class Lighting:
    """Shader inputs derived from a look (linear RGB, CARLA world frame).

    sun_dir: (3,) toward the sun. sun_rgb: direct sun radiance on a surface facing it.
    sky_zenith, sky_horizon: sky colours. ambient_sky, ambient_ground: hemispheric
    ambient from above and below. fog_rgb, fog_sigma (1/m), fog_start (m).
    shadow_strength: 0 … 1 share of the direct light a shadow removes.
    white_balance: (3,) per-channel gain of the camera's white balance × exposure.
    """

    sun_dir: np.ndarray
    sun_rgb: np.ndarray
    sky_zenith: np.ndarray
    sky_horizon: np.ndarray
    ambient_sky: np.ndarray
    ambient_ground: np.ndarray
    fog_rgb: np.ndarray
    fog_sigma: float
    fog_start: float
    shadow_strength: float
    white_balance: np.ndarray
    cloud_cover: float
    wetness: float
    deposits: float


HAZE_SIGMA = 0.0007  # 1/m: clear-air haze that fades far buildings toward the horizon
FOG_SIGMA_MAX = 0.08  # 1/m at fog_density = 100


def lighting(look: LookConfig) -> Lighting:
    """Derive the renderer's light, sky and fog from a look (pure function)."""
    w, cam = look.weather, look.camera
    clouds = float(np.clip(w.cloudiness, 0, 100)) / 100.0
    rain = float(np.clip(w.precipitation, 0, 100)) / 100.0
    alt = float(w.sun_altitude_angle)
    d = sun_direction(w)
    # sun colour reddens toward the horizon (longer path through the air)
    s = float(np.clip(math.sin(math.radians(max(alt, 0.0))), 0.0, 1.0))
    warm = np.array([1.0, 0.55 + 0.45 * s ** 0.5, 0.25 + 0.75 * s ** 0.7])
    day = float(np.clip((alt + 4.0) / 12.0, 0.0, 1.0))  # 0 at -4° (night) … 1 at 8°
    direct = 2.3 * day * (1.0 - 0.88 * clouds ** 1.5) * (1.0 - 0.5 * rain)
    sun_rgb = direct * warm * (0.35 + 0.65 * s ** 0.35)
    # clear sky: deep blue zenith, pale horizon; overcast: grey
    zen_clear = np.array([0.06, 0.15, 0.46])
    hor_clear = np.array([0.42, 0.52, 0.66])
    grey = np.array([0.45, 0.47, 0.50]) * (1.0 - 0.35 * rain)
    sky_level = 0.08 + 0.92 * day * (0.55 + 0.45 * s ** 0.5)
    zen = (zen_clear * (1 - clouds) + grey * 0.9 * clouds) * sky_level
    hor = (hor_clear * (1 - clouds) + grey * clouds) * sky_level
    dusk = float(np.clip(1.0 - alt / 15.0, 0.0, 1.0)) * day * (1 - clouds)
    hor = hor * (1 - 0.6 * dusk) + np.array([0.95, 0.55, 0.30]) * sky_level * 0.6 * dusk
    amb_sky = 0.5 * (0.5 * zen + 0.5 * hor) + 0.3 * clouds * sky_level
    amb_ground = 0.35 * hor * np.array([0.9, 0.85, 0.8])
    fog_sigma = HAZE_SIGMA + FOG_SIGMA_MAX * (float(np.clip(w.fog_density, 0, 100)) / 100.0) ** 1.5
    fog_sigma += 0.004 * rain
    fog_rgb = 0.5 * hor + 0.5 * np.array([0.50, 0.52, 0.55]) * sky_level
    wb = 1.0 / _kelvin_rgb(cam.temp)  # balanced for light of temp K (the sun is 6500 K)
    tint = float(np.clip(cam.tint, -1, 1))
    wb = wb * np.array([1.0 + 0.1 * tint, 1.0 - 0.2 * tint, 1.0 + 0.1 * tint])
    wb = wb / float(wb @ np.array([0.2126, 0.7152, 0.0722]))  # keep luminance
    wb = wb * 2.0 ** float(cam.exposure_compensation)
    return Lighting(
        sun_dir=d, sun_rgb=sun_rgb, sky_zenith=zen, sky_horizon=hor, ambient_sky=amb_sky,
        ambient_ground=amb_ground, fog_rgb=fog_rgb, fog_sigma=fog_sigma,
        fog_start=max(0.0, float(w.fog_distance)),
        shadow_strength=float(np.clip(1.0 - 1.1 * clouds, 0.0, 1.0)) * day,
        white_balance=wb, cloud_cover=clouds,
        wetness=float(np.clip(w.wetness, 0, 100)) / 100.0,
        deposits=float(np.clip(w.precipitation_deposits, 0, 100)) / 100.0,
    )


def with_weather(look: LookConfig, **kw) -> LookConfig:
    """A copy of ``look`` with some weather fields replaced (CARLA names)."""
    return replace(look, weather=replace(look.weather, **kw))
