"""Embedding vehicle crops with an ONNX ReID model (onnxruntime; no torch).

``ReidEmbedder`` takes crops as file paths, Pillow images or (H, W, 3) uint8 RGB arrays
and returns (N, D) float32 L2-normalised embeddings (D = 512 for one exported model, the
sum of its members' for an ensemble, `dashtraj.train.reid_ensemble`): the squared L2
distance of two embeddings is 2 − 2 × their cosine similarity, so an inner-product and an
L2 gallery rank the same. The default model is the one shipped in ``dashtraj/data/reid/``.

Example:
    >>> e = ReidEmbedder()  # doctest: +SKIP
    >>> e.embed(["a.jpg", "b.jpg"]).shape  # doctest: +SKIP
    (2, 512)
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from importlib import resources
from pathlib import Path

import numpy as np

from dashtraj.errors import DashtrajError
from dashtraj.reid.evaluate import l2_normalize
from dashtraj.reid.preprocess import resize_uint8

SHIPPED_MODEL = "efficientnet_lite0_cpu.onnx"
"""File name of the shipped model in ``dashtraj/data/reid/``."""

JOIN_MODEL = "efficientnet_lite0_join.onnx"
"""File name of the shipped track-join model in ``dashtraj/data/reid/``: the shipped model
trained two more epochs on images shrunk to dashcam sizes (``--lowres 0.3``). It joins one
camera's tracks of one vehicle offline (`dashtraj.perception.track.Relink`, `tracker eval`'s
``+relink``) better than the shipped model and finds the target worse; its card says why."""


class ModelFileError(DashtrajError):
    """An ONNX model file is missing or not a dashtraj ReID model."""


def _packaged(name: str) -> Path:
    """Path of a file shipped in ``dashtraj/data/reid/``."""
    return Path(str(resources.files("dashtraj") / "data" / "reid" / name))


def shipped_model_path() -> Path:
    """Path of the ONNX ReID model shipped inside the package."""
    return _packaged(SHIPPED_MODEL)


def join_model_path() -> Path:
    """Path of the ONNX track-join model shipped inside the package (`JOIN_MODEL`)."""
    return _packaged(JOIN_MODEL)


class ReidEmbedder:
    """An ONNX ReID model on onnxruntime's CPU provider.

    Args:
        model_path: ``.onnx`` file (None: the shipped model).
        threads: intra-op threads (default 2, this project's machines).
        flip: test-time augmentation: each crop is also embedded mirrored left-right and
            the two embeddings are summed before the L2 normalisation (twice the
            compute; the models train with flips, a vehicle's mirror image is the same
            vehicle). Off by default: the shipped threshold is calibrated without it.
    """

    def __init__(self, model_path: str | Path | None = None, threads: int = 2,
                 flip: bool = False):
        import onnxruntime as ort

        p = Path(model_path) if model_path is not None else shipped_model_path()
        if not p.is_file():
            raise ModelFileError(f"{p}: no such ONNX model")
        so = ort.SessionOptions()
        so.intra_op_num_threads = threads
        so.inter_op_num_threads = 1
        # idle worker threads sleep instead of spinning (shared, oversubscribed CPUs)
        so.add_session_config_entry("session.intra_op.allow_spinning", "0")
        try:
            self.session = ort.InferenceSession(str(p), so, providers=["CPUExecutionProvider"])
        except Exception as e:  # onnxruntime raises its own Fail/InvalidGraph types
            raise ModelFileError(f"{p}: not a readable ONNX model ({e})") from e
        meta = self.session.get_modelmeta().custom_metadata_map
        shape = self.session.get_inputs()[0].shape
        try:
            self.height = int(meta.get("input_height", shape[2]))
            self.width = int(meta.get("input_width", shape[3]))
        except (TypeError, ValueError, IndexError) as e:
            raise ModelFileError(f"{p}: no fixed input height/width") from e
        self.mean = np.asarray(json.loads(meta.get("mean", "[0.485, 0.456, 0.406]")),
                               np.float32)
        self.std = np.asarray(json.loads(meta.get("std", "[0.229, 0.224, 0.225]")), np.float32)
        self.path = p
        self.flip = bool(flip)
        self.metadata = dict(meta)
        self._input = self.session.get_inputs()[0].name
        out = self.session.get_outputs()[0].shape
        try:
            self.dim = int(meta.get("feature_dim", out[1]))
        except (TypeError, ValueError, IndexError) as e:
            raise ModelFileError(f"{p}: no fixed embedding size") from e

    def preprocess(self, crops: Iterable) -> np.ndarray:
        """Crops → (N, H, W, 3) uint8 at the model's input size."""
        arrs = [resize_uint8(c, self.height, self.width) for c in crops]
        if not arrs:
            return np.zeros((0, self.height, self.width, 3), np.uint8)
        return np.stack(arrs)

    def embed_array(self, images: np.ndarray, batch_size: int = 64,
                    normalize: bool = True) -> np.ndarray:
        """(N, H, W, 3) uint8 at the input size → (N, `dim`) float32 embeddings."""
        images = np.asarray(images)
        if images.ndim != 4 or images.shape[1:] != (self.height, self.width, 3):
            raise ValueError(f"images must be (N, {self.height}, {self.width}, 3) uint8, got "
                             f"{images.shape}")
        out = []
        for i in range(0, len(images), batch_size):
            x = images[i:i + batch_size].astype(np.float32) / 255.0
            x = ((x - self.mean) / self.std).transpose(0, 3, 1, 2)
            f = self.session.run(None, {self._input: np.ascontiguousarray(x)})[0]
            if self.flip:
                xf = np.ascontiguousarray(x[..., ::-1])
                f = f + self.session.run(None, {self._input: xf})[0]
            out.append(f)
        f = np.concatenate(out) if out else np.zeros((0, self.dim), np.float32)
        return l2_normalize(f) if normalize else f.astype(np.float32)

    def embed_boxes(self, rgb: np.ndarray, boxes: np.ndarray,
                    min_height_px: float = 0.0) -> np.ndarray:
        """The boxes (N, 4; x0, y0, x1, y1 pixels) of one (H, W, 3) uint8 image embedded:
        (N, `dim`) float32, L2-normalised; each box is cropped with 10 % margin as the
        sightings' crops are (`dashtraj.datasets.frames.crop_vehicle`). A box under
        ``min_height_px`` high gets a NaN row."""
        from dashtraj.datasets.frames import crop_vehicle

        boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
        big = np.flatnonzero(boxes[:, 3] - boxes[:, 1] >= min_height_px)
        out = np.full((len(boxes), self.dim), np.nan, np.float32)
        if len(big):
            out[big] = self.embed([crop_vehicle(rgb, boxes[i], 0.1) for i in big])
        return out

    def embed(self, crops: Iterable, batch_size: int = 64, normalize: bool = True) -> np.ndarray:
        """Crops (paths, Pillow images or uint8 RGB arrays) → (N, `dim`) float32 embeddings."""
        crops = list(crops)
        out = [self.embed_array(self.preprocess(crops[i:i + 256]), batch_size, normalize)
               for i in range(0, len(crops), 256)]
        return np.concatenate(out) if out else np.zeros((0, self.dim), np.float32)
