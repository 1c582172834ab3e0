"""Camera effects applied to a rendered image after readback (numpy + Pillow).

Exposure, white balance, tone curve, gamma, vignetting and sensor noise run in the
colour pass's shader (``dashtraj.render.shaders``); what needs whole-image context
runs here, in this order:

1. rain streaks (``Weather.precipitation`` > 0): ``round(precipitation × 1.2 × W / 640)``
   thin bright streaks falling slightly slanted, 8–28 px long at 640 px width, 12–30 %
   opacity, positions from a generator seeded by the look's seed and the camera pose;
2. blur (``CameraLook.blur_radius`` > 0): Gaussian, sigma = blur_radius × W / 640 px
   (repeated binomial passes, ``blur``);
3. JPEG compression (``CameraLook.jpeg_quality`` in 1 … 99): encoded and decoded
   with Pillow at that quality.

Every step is deterministic: the same image, look and pose give the same bytes. None
of them touches labels (they come from the id pass).
"""

from __future__ import annotations

import functools
import io
import zlib

import numpy as np


def _pose_rng(look, pose) -> np.random.Generator:
    key = zlib.crc32(np.array([*pose, look.seed], np.float64).tobytes())
    return np.random.default_rng([int(look.seed) & 0xFFFFFFFF, key])


def rain_streaks(rgb: np.ndarray, precipitation: float, rng: np.random.Generator) -> np.ndarray:
    """Blend rain streaks into an (H, W, 3) uint8 image (returns a new array)."""
    h, w = rgb.shape[:2]
    s = w / 640.0
    n = round(float(precipitation) * 1.2 * s)
    if n <= 0:
        return rgb
    x0 = rng.uniform(0, w, n)
    y0 = rng.uniform(-10 * s, h, n)
    length = rng.uniform(8, 28, n) * s
    alpha = rng.uniform(0.12, 0.30, n)
    slant = rng.normal(0.12, 0.03)
    steps = int(np.ceil(28 * s))
    t = np.linspace(0.0, 1.0, steps)
    xs = (x0[:, None] + slant * length[:, None] * t).round().astype(np.int64)
    ys = (y0[:, None] + length[:, None] * t).round().astype(np.int64)
    a = np.repeat(alpha, steps)
    xs, ys = xs.ravel(), ys.ravel()
    ok = (xs >= 0) & (xs < w) & (ys >= 0) & (ys < h)
    xs, ys, a = xs[ok], ys[ok], a[ok]
    # later streaks over earlier ones: apply in order (duplicates resolved by last write);
    # only the streaks' pixels change (float32 blend, + ½, clipped, truncated)
    out = rgb.copy()
    val = rgb[ys, xs].astype(np.float32) * (1 - a[:, None]) + 215.0 * a[:, None]
    out[ys, xs] = np.clip(val + 0.5, 0, 255).astype(np.uint8)
    return out


def _binomial(x: np.ndarray) -> np.ndarray:
    """One separable [1 2 1] / 4 pass (variance 0.5 px² per axis) over an (H, W, 3)
    uint16 image, edges repeated."""
    p = np.pad(x, ((1, 1), (1, 1), (0, 0)), mode="edge")
    y = p[:, :-2] + 2 * p[:, 1:-1] + p[:, 2:]
    return (y[:-2] + 2 * y[1:-1] + y[2:] + 8) >> 4


def blur(rgb: np.ndarray, sigma_px: float) -> np.ndarray:
    """Gaussian blur of an (H, W, 3) uint8 image, sigma in pixels: k = ⌊2σ²⌋ binomial
    passes (variance 0.5 px² each) and a linear blend toward one more pass for the
    rest of the variance (numpy; several times faster than Pillow's GaussianBlur for
    the small sigmas of a camera)."""
    if sigma_px <= 0:
        return rgb
    var = 2.0 * float(sigma_px) ** 2
    k = int(var)
    x = rgb.astype(np.uint16)
    for _ in range(k):
        x = _binomial(x)
    w = var - k
    if w > 1e-6:
        # x (1 − w) + binomial(x) w + ½, truncated: both operands are 0 … 255 (a binomial
        # pass never leaves that range), so a 256 × 256 table of the same float64
        # expression gives the same bytes as evaluating it per pixel, several times faster
        x = _blend_table(w)[(x << 8) | _binomial(x)]
    return np.minimum(x, 255).astype(np.uint8)


@functools.lru_cache(maxsize=64)
def _blend_table(w: float) -> np.ndarray:
    """(65536,) uint16: entry a·256 + b = ⌊a (1 − w) + b w + ½⌋ for a, b in 0 … 255 (float64,
    evaluated as ``blur`` did per pixel)."""
    a = np.arange(256, dtype=np.uint16)[:, None]
    b = np.arange(256, dtype=np.uint16)[None, :]
    return (a * (1.0 - w) + b * w + 0.5).astype(np.uint16).ravel()


def jpeg_roundtrip(rgb: np.ndarray, quality: int) -> np.ndarray:
    """The image after JPEG encoding at ``quality`` (1 … 99) and decoding (Pillow)."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb)).save(buf, format="JPEG", quality=int(quality))
    buf.seek(0)
    return np.asarray(Image.open(buf).convert("RGB"))


def camera_post(rgb: np.ndarray, look, pose) -> np.ndarray:
    """Apply the look's post-readback effects (module docstring) to an (H, W, 3) uint8
    image; returns it unchanged (same object) when none is on."""
    if look.legacy:
        return rgb
    w = rgb.shape[1]
    cam, weather = look.camera, look.weather
    if weather.precipitation > 0:
        rgb = rain_streaks(rgb, weather.precipitation, _pose_rng(look, pose))
    if cam.blur_radius > 0:
        rgb = blur(rgb, float(cam.blur_radius) * w / 640.0)
    if 0 < int(cam.jpeg_quality) < 100:
        rgb = jpeg_roundtrip(rgb, int(cam.jpeg_quality))
    if not rgb.flags.writeable or not rgb.flags.c_contiguous:
        rgb = np.ascontiguousarray(rgb).copy()
    return rgb
