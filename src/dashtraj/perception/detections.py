"""Detections of one frame and the `Detector` protocol every detector follows.

A detector turns one rendered frame into boxes, scores and class ids:

- ``boxes``: (N, 4) float64, (x0, y0, x1, y1), image pixels (continuous coordinates,
  top-left image corner at (0, 0), exclusive ends as the renderer's labels);
- ``scores``: (N,) float64 in [0, 1];
- ``class_ids``: (N,) int64, index into `DETECTION_CLASSES` (vehicle class ×
  orientation, the vehicle orientation dataset's 15 classes).

Two detectors exist, chosen by name with `build_detector`:

- ``oracle``: the renderer's exact visible boxes and labels (every vehicle with at
  least `OracleDetector.min_height_px` rows and `min_visible_fraction` of its
  silhouette visible; score 1). It also knows each box's vehicle id (`truth_ids`).
- a path to an ``.onnx`` model: ``dashtraj.perception.detect.YoloDetector`` (the ONNX run
  time detector).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from dashtraj.errors import DashtrajError
from dashtraj.perception.detect import DEFAULT_MIN_SCORE
from dashtraj.world.camera import DETECTION_CLASSES

ORIENTATION_OF_CLASS: tuple[str, ...] = tuple(c.split("_")[1] for c in DETECTION_CLASSES)
"""Orientation (front / back / side) of each class id."""

VEHICLE_CLASS_OF_CLASS: tuple[str, ...] = tuple(c.split("_")[0] for c in DETECTION_CLASSES)
"""Vehicle class (car, truck, bus, motorcycle, bicycle) of each class id."""

VEHICLE_CLASS_INDEX: np.ndarray = np.array(
    [("car", "truck", "bus", "motorcycle", "bicycle").index(v) for v in VEHICLE_CLASS_OF_CLASS])
"""(15,) vehicle-class index (0 car … 4 bicycle) of each class id: Eq. 1's η."""


class DetectorError(DashtrajError):
    """A detector cannot be built (unknown name, missing model file or module)."""


@dataclass(frozen=True, slots=True, eq=False)
class Detections:
    """The detections of one frame (units and order in the module docstring).

    ``truth_ids`` (N,) int64 holds the vehicle id each box belongs to when the detector
    knows it (the oracle) or when it was matched to the renderer's labels, −1 otherwise.
    """

    boxes: np.ndarray
    scores: np.ndarray
    class_ids: np.ndarray
    truth_ids: np.ndarray

    def __len__(self) -> int:
        return len(self.scores)

    @classmethod
    def empty(cls) -> Detections:
        return cls(np.zeros((0, 4)), np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64))

    def take(self, index) -> Detections:
        return Detections(self.boxes[index], self.scores[index], self.class_ids[index],
                          self.truth_ids[index])


@runtime_checkable
class Detector(Protocol):
    """Anything that detects vehicles in one frame.

    ``detect(frame)`` takes a `dashtraj.datasets.frames.RecordingFrame` (its
    ``frame_data.rgb`` is the (H, W, 3) uint8 image) and returns `Detections`.
    """

    name: str

    def detect(self, frame) -> Detections: ...


@dataclass
class OracleDetector:
    """The renderer's exact visible boxes and labels as detections (score 1).

    Attributes:
        min_height_px: drop boxes fewer than this many pixels high (a detector's floor).
        min_visible_fraction: drop vehicles with less of their silhouette visible.
    """

    min_height_px: float = 8.0
    min_visible_fraction: float = 0.1
    name: str = "oracle"

    def detect(self, frame) -> Detections:
        boxes, cls, ids = [], [], []
        for lab, vid in zip(frame.frame_data.labels, frame.vehicle_ids, strict=True):
            b = lab.visible_box
            if b is None or lab.visible_fraction < self.min_visible_fraction:
                continue
            if b[3] - b[1] < self.min_height_px:
                continue
            boxes.append(b)
            cls.append(lab.detection_class_id)
            ids.append(vid)
        if not boxes:
            return Detections.empty()
        return Detections(np.asarray(boxes, np.float64), np.ones(len(boxes)),
                          np.asarray(cls, np.int64), np.asarray(ids, np.int64))


def truth_of(frame, min_height_px: float = 8.0, min_visible_fraction: float = 0.1) -> Detections:
    """The ground truth of a frame: the oracle's detections (same thresholds)."""
    return OracleDetector(min_height_px, min_visible_fraction).detect(frame)


def match_truth(det: Detections, truth: Detections, min_iou: float = 0.5) -> np.ndarray:
    """Vehicle id of each detection: its truth box by the Hungarian method on IoU (≥ min_iou),
    else −1. Returns (N,) int64."""
    from scipy.optimize import linear_sum_assignment

    out = np.full(len(det), -1, np.int64)
    if len(det) == 0 or len(truth) == 0:
        return out
    iou = iou_matrix(det.boxes, truth.boxes)
    r, c = linear_sum_assignment(-iou)
    ok = iou[r, c] >= min_iou
    out[r[ok]] = truth.truth_ids[c[ok]]
    return out


def depicted_vehicles(frame, boxes: np.ndarray, min_fraction: float = 0.25,
                      min_share: float = 0.5, min_share_fraction: float = 0.05) -> np.ndarray:
    """Vehicle id each box *shows*, from the renderer's instance image; −1 for none.

    The vehicle with the most pixels inside the box shows in it when those pixels cover at
    least `min_fraction` of the box, or when the box holds at least `min_share` of that
    vehicle's visible pixels in the frame and they cover at least `min_share_fraction`
    of the box (a thin vehicle, a motorcycle or bicycle seen from behind, fills little of
    its own box). Returns (N,) int64.

    `match_truth` pairs detections with truth boxes one to one at IoU ≥ 0.5, the
    detection protocol: a second box on one vehicle (a duplicate of another orientation
    class), or a box of part of it (a motorcycle without its rider, a car's front half),
    matches no truth box. For re-identification a crop is the target's when it shows
    the target, which this says from the pixels (evaluation only: the renderer's
    ground truth). `frame` is a `dashtraj.datasets.frames.RecordingFrame`.
    """
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    out = np.full(len(b), -1, np.int64)
    inst = frame.frame_data.instance
    if not len(b) or inst is None:  # a drive's frames have no instance image
        return out
    h, w = inst.shape
    labels = frame.frame_data.labels
    vid_of = {lab.instance_id: int(v) for lab, v in zip(labels, frame.vehicle_ids, strict=True)}
    visible = {lab.instance_id: lab.visible_pixels for lab in labels}  # pixels in the frame
    for i, (x0, y0, x1, y1) in enumerate(b):
        c0, r0 = max(0, math.floor(x0)), max(0, math.floor(y0))
        c1, r1 = min(w, math.ceil(x1)), min(h, math.ceil(y1))
        if c1 <= c0 or r1 <= r0:
            continue
        ids, n = np.unique(inst[r0:r1, c0:c1], return_counts=True)
        keep = ids != 0
        ids, n = ids[keep], n[keep]
        if not len(ids):
            continue
        j = int(np.argmax(n))
        v, area = int(ids[j]), (r1 - r0) * (c1 - c0)
        if v in vid_of and (n[j] >= min_fraction * area
                            or (n[j] >= min_share * visible[v]
                                and n[j] >= min_share_fraction * area)):
            out[i] = vid_of[v]
    return out


def intersection_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection area of every box of a (N, 4) with every box of b (M, 4), xyxy
    pixels → (N, M) px²."""
    a = np.asarray(a, np.float64).reshape(-1, 4)
    b = np.asarray(b, np.float64).reshape(-1, 4)
    lo = np.maximum(a[:, None, :2], b[None, :, :2])
    hi = np.minimum(a[:, None, 2:], b[None, :, 2:])
    return np.clip(hi[..., 0] - lo[..., 0], 0, None) * np.clip(hi[..., 1] - lo[..., 1], 0, None)


def iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU of every box of a (N, 4) with every box of b (M, 4), xyxy pixels → (N, M)."""
    a = np.asarray(a, np.float64).reshape(-1, 4)
    b = np.asarray(b, np.float64).reshape(-1, 4)
    inter = intersection_matrix(a, b)
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    union = area_a[:, None] + area_b[None, :] - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)


class _ModelDetector:
    """Adapter of the ONNX run time (`dashtraj.perception.detect.YoloDetector`) to `Detector`;
    each detection also gets the vehicle id of the truth box it matches (for evaluation).

    ``agnostic_iou``: also suppress boxes of *other* classes overlapping a better one by
    more than this IoU (class-agnostic NMS; None: class-aware only, the model's own
    NMS). The 15 classes are one vehicle seen from the front, back or side, so a
    vehicle has exactly one; class-aware NMS keeps one box per orientation class on
    the same car (measured on town01 seed 20, 120 frames, the shipped detector: 76
    duplicate boxes on a true vehicle; agnostic IoU 0.5: 6, 0.4: none, same recall of
    vehicles >= 24 px; 0.3 lost some). Each duplicate becomes a duplicate track. With
    it, a box that lies mostly inside a better one and is a sizeable part of it (a
    sub-box of the same vehicle, IoU below the threshold) is dropped too
    (`_part_of_better`)."""

    def __init__(self, path: Path, threads: int = 2, agnostic_iou: float | None = None,
                 min_score: float = DEFAULT_MIN_SCORE, classifier: str | Path | None = None):
        from dashtraj.perception.detect import YoloDetector

        self.name = path.name
        self._model = YoloDetector(path, threads=threads, conf=min_score,
                                   classifier=classifier)
        self.agnostic_iou = agnostic_iou

    def detect(self, frame) -> Detections:
        from dashtraj.perception.detect import nms

        out = self._model.detect([frame.frame_data.rgb])[0]
        boxes = np.asarray(out.boxes, np.float64).reshape(-1, 4)
        scores = np.asarray(out.scores, np.float64)
        classes = np.asarray(out.class_ids, np.int64)
        if self.agnostic_iou is not None and len(scores) > 1:
            keep = np.sort(nms(boxes, scores, self.agnostic_iou))
            boxes, scores, classes = boxes[keep], scores[keep], classes[keep]
            keep = np.flatnonzero(~_part_of_better(boxes, scores))
            boxes, scores, classes = boxes[keep], scores[keep], classes[keep]
        d = Detections(boxes, scores, classes, np.full(len(scores), -1, np.int64))
        return Detections(d.boxes, d.scores, d.class_ids, match_truth(d, truth_of(frame)))


def _part_of_better(boxes: np.ndarray, scores: np.ndarray, inside: float = 0.8,
                    part: float = 0.25) -> np.ndarray:
    """(N,) bool: boxes with at least `inside` of their area within a higher-scoring box
    whose area they are at least `part` of (a piece of the same vehicle; a far vehicle
    seen past a near one is a smaller fraction of its box).

    Example:
        >>> _part_of_better(np.array([[0, 0, 50, 40], [25, 10, 50, 40], [40, 30, 45, 34]]),
        ...                 np.array([0.9, 0.8, 0.7])).tolist()
        [False, True, False]
    """
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    s = np.asarray(scores, np.float64)
    area = (b[:, 2] - b[:, 0]).clip(0) * (b[:, 3] - b[:, 1]).clip(0)
    inter = intersection_matrix(b, b)  # inter[i, j]
    with np.errstate(invalid="ignore", divide="ignore"):
        frac_in = np.where(area[:, None] > 0, inter / area[:, None], 0.0)
        frac_of = np.where(area[None, :] > 0, area[:, None] / area[None, :], 0.0)
    better = s[None, :] > s[:, None]
    return np.any(better & (frac_in >= inside) & (frac_of >= part), axis=1)


AGNOSTIC_NMS_IOU = 0.45
"""Default class-agnostic NMS IoU of a detector model (`_ModelDetector`) in `perceive`, the
experiments and the evaluations on rendered frames: one box per vehicle instead of one per
orientation class. Commands take ``--agnostic-nms IOU|none``."""

CONFIRM_SCORE = 0.5
"""Default `dashtraj.perception.track.EgoTracker.confirm_score`: a track is reported once one
of its boxes scored at least this much (ByteTrack's high-score threshold)."""

DETECTORS: tuple[str, ...] = ("oracle",)
"""Detector names; any other value must be a path to an .onnx model."""


def build_detector(name: str, threads: int = 2, agnostic_iou: float | None = None,
                   min_score: float = DEFAULT_MIN_SCORE,
                   classifier: str | Path | None = None) -> Detector:
    """``"oracle"`` → `OracleDetector`; a path to an ``.onnx`` file → the ONNX detector
    (`threads`: its onnxruntime intra-op threads; `agnostic_iou`: class-agnostic NMS,
    see `_ModelDetector`; `min_score`: a model's smallest kept score; `classifier`: its
    second stage, a box classifier ONNX (`dashtraj.perception.detect.BoxClassifier`),
    or None; the oracle's boxes ignore it).

    Raises:
        DetectorError: neither a known name nor an existing .onnx file.
    """
    if name == "oracle":
        return OracleDetector()
    p = Path(name)
    if p.suffix.lower() != ".onnx":
        raise DetectorError(f"unknown detector {name!r}; valid: oracle or a path to an .onnx "
                            "model")
    if not p.is_file():
        raise DetectorError(f"--detector {p}: no such model file")
    return _ModelDetector(p, threads, agnostic_iou, min_score, classifier)
