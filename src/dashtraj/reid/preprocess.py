"""Image preprocessing shared by training and the ONNX run time (numpy + Pillow).

A crop is converted to RGB, resized (bilinear, aspect ratio not kept, as torchreid)
to the model's input height × width, scaled to [0, 1] and normalised per channel with
ImageNet's mean and standard deviation; the network takes (N, 3, H, W) float32.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


def load_rgb(item):
    """A Pillow RGB image from a path, a Pillow image or an (H, W, 3) uint8 array."""
    from PIL import Image

    if isinstance(item, str | Path):
        with Image.open(item) as im:
            return im.convert("RGB")
    if isinstance(item, Image.Image):
        return item.convert("RGB")
    a = np.asarray(item)
    if a.ndim != 3 or a.shape[2] != 3 or a.dtype != np.uint8:
        raise ValueError(f"an image array must be (H, W, 3) uint8, got {a.shape} {a.dtype}")
    return Image.fromarray(a)


def resize_uint8(item, height: int, width: int) -> np.ndarray:
    """The crop resized (bilinear) to (height, width, 3) uint8."""
    from PIL import Image

    im = load_rgb(item)
    if im.size != (width, height):
        im = im.resize((width, height), Image.Resampling.BILINEAR)
    return np.asarray(im, np.uint8)


def to_input(batch: np.ndarray) -> np.ndarray:
    """(N, H, W, 3) uint8 → (N, 3, H, W) float32, normalised (module docstring)."""
    x = np.asarray(batch, np.float32) / 255.0
    x = (x - np.asarray(IMAGENET_MEAN, np.float32)) / np.asarray(IMAGENET_STD, np.float32)
    return np.ascontiguousarray(x.transpose(0, 3, 1, 2))
