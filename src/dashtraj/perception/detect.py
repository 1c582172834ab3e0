"""Vehicle detection at run time: any YOLO ONNX export in the ultralytics v8/11 layout,
run with onnxruntime (no torch).

Pipeline (`YoloDetector.detect`): letterbox every frame to the model's input size
(aspect kept, grey 114 padding split evenly), batch, run, decode the output
``(B, 4 + nc, N)`` (rows cx, cy, w, h in input pixels, then nc class scores), keep each
cell's best class above ``conf``, class-aware NMS at IoU ``iou``, and map the boxes back
to the frame's pixels (x0, y0, x1, y1; clipped to the frame).

Class names come from the model's metadata (``names``, as ultralytics writes it:
``"{0: 'car', 1: 'bus'}"``) or from a ``data.yaml``; a model whose output has a
different number of classes than the names is refused (`DetectorError`).

Example:
    >>> det = YoloDetector()                      # the shipped 15-class model
    >>> out = det.detect([frame_rgb])[0]          # doctest: +SKIP
    >>> out.boxes, out.scores, out.labels         # doctest: +SKIP
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dashtraj.errors import DashtrajError, read_utf8

PAD_VALUE = 114
"""Grey of the letterbox padding (ultralytics')."""


class DetectorError(DashtrajError):
    """A model or names file that cannot be used; the message names the file."""


SHIPPED_DETECTORS = {"shipped": "detector", "gpu": "detector_gpu"}
"""The package's detectors by name, each ``dashtraj/data/<folder>/detector.onnx`` with its
card (MODEL.md): ``shipped`` (the default; cpu recipe on Mesa llvmpipe renders, the
built-in world's renderer) and ``gpu`` (gpu recipe on renders of NVIDIA's OpenGL: better
on real CARLA frames, worse on the built-in world's renders)."""


def default_model_path(name: str = "shipped") -> Path:
    """A shipped detector's ONNX file (``SHIPPED_DETECTORS``; default the default one)."""
    return (Path(__file__).resolve().parent.parent / "data" / SHIPPED_DETECTORS[name]
            / "detector.onnx")


# ----------------------------------------------------------------------------- letterbox
@dataclass(frozen=True)
class Letterbox:
    """How a frame was placed in the network input.

    scale: input pixels per frame pixel. pad_x, pad_y: left and top padding, input
    pixels. frame_w, frame_h: the frame's size, pixels.
    """

    scale: float
    pad_x: int
    pad_y: int
    frame_w: int
    frame_h: int

    def boxes_to_image(self, det: np.ndarray) -> np.ndarray:
        """Rows [x0, y0, x1, y1, ...] in input pixels -> frame pixels (clipped); the other
        columns are kept. Returns a new float array."""
        out = np.array(det, dtype=np.float64, copy=True).reshape(-1, det.shape[-1]
                                                                 if det.ndim else 4)
        if len(out):
            out[:, [0, 2]] = ((out[:, [0, 2]] - self.pad_x) / self.scale).clip(0, self.frame_w)
            out[:, [1, 3]] = ((out[:, [1, 3]] - self.pad_y) / self.scale).clip(0, self.frame_h)
        return out

    def boxes_to_input(self, boxes: np.ndarray) -> np.ndarray:
        """(K, 4) x0, y0, x1, y1 frame pixels -> input pixels (the inverse, unclipped)."""
        b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4).copy()
        b[:, [0, 2]] = b[:, [0, 2]] * self.scale + self.pad_x
        b[:, [1, 3]] = b[:, [1, 3]] * self.scale + self.pad_y
        return b


def letterbox_geometry(frame_hw: tuple[int, int], input_hw: tuple[int, int]) -> Letterbox:
    """The `Letterbox` of a frame of (H, W) pixels in an input of (H, W) pixels."""
    h0, w0 = frame_hw
    h, w = input_hw
    r = min(h / h0, w / w0)
    nw, nh = round(w0 * r), round(h0 * r)
    return Letterbox(scale=r, pad_x=(w - nw) // 2, pad_y=(h - nh) // 2, frame_w=w0, frame_h=h0)


def letterbox(rgb: np.ndarray, input_hw: tuple[int, int]) -> tuple[np.ndarray, Letterbox]:
    """Resize (bilinear, aspect kept) and pad an (H, W, 3) uint8 frame to ``input_hw``.

    Returns the (H_in, W_in, 3) uint8 image and its `Letterbox`.
    """
    from PIL import Image

    lb = letterbox_geometry(rgb.shape[:2], input_hw)
    h, w = input_hw
    nw, nh = round(lb.frame_w * lb.scale), round(lb.frame_h * lb.scale)
    img = rgb if (nw, nh) == (lb.frame_w, lb.frame_h) else np.asarray(
        Image.fromarray(rgb).resize((nw, nh), Image.BILINEAR))
    out = np.full((h, w, 3), PAD_VALUE, np.uint8)
    out[lb.pad_y:lb.pad_y + nh, lb.pad_x:lb.pad_x + nw] = img
    return out, lb


# ----------------------------------------------------------------------------- NMS
def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(Ka, Kb) IoU of boxes (x0, y0, x1, y1)."""
    a = np.asarray(a, np.float64).reshape(-1, 4)
    b = np.asarray(b, np.float64).reshape(-1, 4)
    iw = (np.minimum(a[:, None, 2], b[None, :, 2])
          - np.maximum(a[:, None, 0], b[None, :, 0])).clip(0)
    ih = (np.minimum(a[:, None, 3], b[None, :, 3])
          - np.maximum(a[:, None, 1], b[None, :, 1])).clip(0)
    inter = iw * ih
    aa = ((a[:, 2] - a[:, 0]).clip(0) * (a[:, 3] - a[:, 1]).clip(0))[:, None]
    ab = ((b[:, 2] - b[:, 0]).clip(0) * (b[:, 3] - b[:, 1]).clip(0))[None, :]
    union = aa + ab - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)


def nms(boxes: np.ndarray, scores: np.ndarray, iou: float,
        classes: np.ndarray | None = None, max_keep: int | None = None) -> np.ndarray:
    """Greedy NMS: indices of the kept boxes, best score first.

    A box is dropped when it overlaps a kept, higher-scoring box *of the same class*
    (``classes`` given) or of any class (None) by IoU > ``iou``. Ties in score keep the
    lower index first (stable order). ``max_keep``: stop once that many are kept (the
    first ``max_keep`` of the full answer; an early model scored at conf 0.001 has
    thousands of candidates that suppress few others, and the loop would visit each).
    """
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    order = np.argsort(-np.asarray(scores, np.float64), kind="stable")
    keep = []
    while len(order) and (max_keep is None or len(keep) < max_keep):
        i = order[0]
        keep.append(i)
        rest = order[1:]
        if not len(rest):
            break
        ov = box_iou(boxes[i:i + 1], boxes[rest])[0]
        drop = ov > iou
        if classes is not None:
            drop &= classes[rest] == classes[i]
        order = rest[~drop]
    return np.array(keep, dtype=np.int64)


DEFAULT_MIN_SCORE = 0.25
"""The smallest kept box score of a detector model unless told otherwise (``--min-score``)."""


def postprocess(raw: np.ndarray, conf: float = DEFAULT_MIN_SCORE, iou: float = 0.6,
                max_det: int = 300, max_candidates: int = 10000) -> list[np.ndarray]:
    """Decode an ultralytics-layout output.

    Args:
        raw: (B, 4 + nc, N): cx, cy, w, h (input pixels) and nc class scores in [0, 1].
        conf: smallest kept score. iou: class-aware NMS threshold.
        max_det: most boxes per image. max_candidates: most boxes into NMS (best first).

    Returns:
        per image a (K, 6) float array [x0, y0, x1, y1, score, class], input pixels,
        best score first.
    """
    raw = np.asarray(raw)
    if raw.ndim != 3 or raw.shape[1] < 5:
        raise DetectorError(f"model output has shape {raw.shape}; expected (B, 4 + nc, N)")
    out = []
    for r in raw:
        cls_scores = r[4:]
        cls = cls_scores.argmax(0)
        score = cls_scores[cls, np.arange(r.shape[1])]
        sel = np.flatnonzero(score > conf)
        if len(sel) > max_candidates:
            sel = sel[np.argsort(-score[sel], kind="stable")[:max_candidates]]
        cx, cy, w, h = r[0, sel], r[1, sel], r[2, sel], r[3, sel]
        boxes = np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], 1)
        keep = nms(boxes, score[sel], iou, cls[sel], max_keep=max_det)
        out.append(np.concatenate([boxes[keep], score[sel][keep, None],
                                   cls[sel][keep, None].astype(np.float64)], 1)
                   .astype(np.float64).reshape(-1, 6))
    return out


def read_rgb(path) -> np.ndarray:
    """(H, W, 3) uint8 RGB of an image file.

    Raises:
        DetectorError: the file is missing or not an image Pillow reads (names the file).
    """
    from PIL import Image

    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"))
    except OSError as exc:  # UnidentifiedImageError is an OSError
        raise DetectorError(f"{path}: not a readable image ({exc})") from None


# ----------------------------------------------------------------------------- names
def read_names_yaml(path) -> list[str]:
    """Class names of a YOLO ``data.yaml`` (``names:`` as a mapping ``0: car`` on the
    following lines, a ``- car`` list, or an inline ``[car, bus]`` list).

    Raises DetectorError naming the file when there is no usable ``names``.
    """
    path = Path(path)
    try:
        lines = read_utf8(path, DetectorError).splitlines()
    except OSError as exc:
        raise DetectorError(f"{path}: cannot read ({exc.strerror})") from exc
    for i, line in enumerate(lines):
        if not line.startswith("names:"):
            continue
        rest = line[len("names:"):].strip()
        if rest:
            try:
                val = ast.literal_eval(rest) if rest[0] in "[{" else None
            except (ValueError, SyntaxError):
                val = None
            if val is None:
                # inline list of bare words: [car, bus]
                if rest.startswith("[") and rest.endswith("]"):
                    return [s.strip().strip("'\"") for s in rest[1:-1].split(",") if s.strip()]
                raise DetectorError(f"{path}:{i + 1}: cannot read 'names'")
            return list(val.values()) if isinstance(val, dict) else [str(v) for v in val]
        names: dict[int, str] = {}
        seq: list[str] = []
        for j, sub in enumerate(lines[i + 1:], i + 2):
            if not sub.strip() or sub.lstrip().startswith("#"):
                continue
            if not sub[0].isspace() and not sub.startswith("-"):
                break
            s = sub.strip()
            if s.startswith("- "):
                seq.append(s[2:].strip().strip("'\""))
            elif ":" in s:
                k, v = s.split(":", 1)
                try:
                    names[int(k)] = v.strip().strip("'\"")
                except ValueError:
                    raise DetectorError(f"{path}:{j}: expected 'INDEX: name'") from None
        if names:
            if sorted(names) != list(range(len(names))):
                raise DetectorError(f"{path}: class indices are not 0..{len(names) - 1}")
            return [names[k] for k in range(len(names))]
        if seq:
            return seq
        raise DetectorError(f"{path}:{i + 1}: 'names' is empty")
    raise DetectorError(f"{path}: no 'names:' entry")


def names_from_metadata(meta: dict[str, str]) -> list[str] | None:
    """Class names from ONNX metadata (ultralytics' ``names`` dict text), or None."""
    text = meta.get("names")
    if not text:
        return None
    try:
        val = ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return None
    if isinstance(val, dict):
        return [str(val[k]) for k in sorted(val)]
    if isinstance(val, list | tuple):
        return [str(v) for v in val]
    return None


# ----------------------------------------------------------------------------- detector
@dataclass(frozen=True)
class Detections:
    """The detections of one frame, best score first.

    boxes: (K, 4) float x0, y0, x1, y1, frame pixels. scores: (K,) in [0, 1].
    class_ids: (K,) int. names: the model's class names (index = class id).
    """

    boxes: np.ndarray
    scores: np.ndarray
    class_ids: np.ndarray
    names: tuple[str, ...]

    @property
    def labels(self) -> list[str]:
        """Class name of each detection."""
        return [self.names[int(c)] for c in self.class_ids]

    def __len__(self) -> int:
        return len(self.scores)

    def yolo_lines(self, width: int, height: int, with_score: bool = True) -> list[str]:
        """``class cx cy w h [score]`` lines, normalised by the frame's size."""
        out = []
        for (x0, y0, x1, y1), s, c in zip(self.boxes, self.scores, self.class_ids,
                                          strict=True):
            line = (f"{int(c)} {(x0 + x1) / 2 / width:.6f} {(y0 + y1) / 2 / height:.6f} "
                    f"{(x1 - x0) / width:.6f} {(y1 - y0) / height:.6f}")
            out.append(line + (f" {s:.4f}" if with_score else ""))
        return out


def _session(path: Path, threads: int, spin: bool = True):
    """An onnxruntime CPU session of an ONNX file (DetectorError when it cannot load).
    ``spin=False``: idle worker threads sleep instead of spinning (a second session run
    right after another, whose spinning threads would hold the cores)."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    opts.log_severity_level = 3
    if not spin:
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
    try:
        return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own untyped errors
        raise DetectorError(f"{path}: not a usable ONNX model ({exc})") from exc


class YoloDetector:
    """An ultralytics-layout YOLO ONNX model run with onnxruntime.

    Args:
        model: path of the .onnx file (default: the shipped detector).
        names: class names, or a ``data.yaml`` path, or None to read them from the
            model's metadata.
        conf: smallest kept score. iou: class-aware NMS IoU threshold.
        threads: onnxruntime intra-op threads. batch: frames per run (a model with a
            fixed batch of 1 runs one frame at a time).
        classifier: a second stage (`BoxClassifier` or its ONNX path; None: none): the
            best ``classify_top`` boxes of each frame get their classes from their crops
            (`reclassify`, each class of probability >= `CLASSIFIER_MIN_PROB`); the
            others are dropped. A refining one moves them first,
            ``refine_steps`` times (each time from the crop of the box it moved to; the
            classes are the last crop's).

    Raises:
        DetectorError: unreadable model, no names, or a class count that does not
        match the model's output.
    """

    def __init__(self, model=None, names=None, conf: float = DEFAULT_MIN_SCORE, iou: float = 0.6,
                 threads: int = 2, batch: int = 8, max_det: int = 300, classifier=None,
                 classify_top: int = 100, refine_steps: int | None = None):
        self.path = Path(model) if model is not None else default_model_path()
        if not self.path.is_file():
            raise DetectorError(f"{self.path}: no such model file")
        # with a second stage, the detector's idle threads sleep: spinning, they held the
        # cores while the stage cut crops and ran (bench_detector.py's 40 frames, four
        # steps mirrored: CPU 101 -> 72 ms a frame, wall 51 -> 47 ms); alone they spin
        # (wall 18.5 against 19.9 ms)
        self.session = _session(self.path, threads, spin=classifier is None)
        meta = self.session.get_modelmeta().custom_metadata_map
        self.metadata = dict(meta)
        inp = self.session.get_inputs()[0]
        self.input_name = inp.name
        shape = list(inp.shape)
        if len(shape) != 4:
            raise DetectorError(f"{self.path}: input {inp.name} has shape {shape}; expected "
                                "(B, 3, H, W)")
        h, w = shape[2], shape[3]
        if not (isinstance(h, int) and isinstance(w, int)):
            try:
                h, w = ast.literal_eval(meta.get("imgsz", "[640, 640]"))
            except (ValueError, SyntaxError):
                h, w = 640, 640
        self.input_hw = (int(h), int(w))
        self.fixed_batch = shape[0] if isinstance(shape[0], int) else None
        self.batch = self.fixed_batch or max(1, batch)
        if isinstance(names, str | Path):
            names = read_names_yaml(names)
        if names is None:
            names = names_from_metadata(meta)
        if names is None:
            raise DetectorError(f"{self.path}: no class names in the model's metadata; "
                                "pass a data.yaml (--names)")
        self.names = tuple(names)
        out_shape = self.session.get_outputs()[0].shape
        if len(out_shape) != 3:
            raise DetectorError(f"{self.path}: output has shape {out_shape}; expected "
                                "(B, 4 + nc, N) (ultralytics v8/11 layout)")
        self.conf, self.iou, self.max_det = conf, iou, max_det
        if classifier is not None and not isinstance(classifier, BoxClassifier):
            classifier = BoxClassifier(classifier, threads=threads)
        if classifier is not None and tuple(classifier.names) != self.names:
            raise DetectorError(f"{classifier.path}: its classes ({', '.join(classifier.names[:3])}"
                                f"...) are not the detector's ({', '.join(self.names[:3])}...)")
        self.classifier, self.classify_top = classifier, classify_top
        self.refine_steps = REFINE_STEPS if refine_steps is None else max(1, int(refine_steps))
        if isinstance(out_shape[1], int):
            self._check_nc(out_shape[1])
        else:  # a symbolic class dimension: run one blank frame to learn it
            blank = np.full((self.fixed_batch or 1, *self.input_hw, 3), PAD_VALUE, np.uint8)
            self.run_raw(blank)

    def _check_nc(self, channels: int) -> None:
        if channels - 4 != len(self.names):
            raise DetectorError(
                f"{self.path}: the model predicts {channels - 4} classes but {len(self.names)} "
                f"names were given ({', '.join(self.names[:4])}...); use the data.yaml the "
                "model was trained with")

    @property
    def num_classes(self) -> int:
        return len(self.names)

    def run_raw(self, batch: np.ndarray) -> np.ndarray:
        """(B, H, W, 3) uint8 letterboxed images -> raw (B, 4 + nc, N) output."""
        x = np.ascontiguousarray(batch.transpose(0, 3, 1, 2), dtype=np.float32) / 255.0
        outs = []
        step = self.fixed_batch or len(x)
        for i in range(0, len(x), step):
            outs.append(self.session.run(None, {self.input_name: x[i:i + step]})[0])
        raw = np.concatenate(outs, 0)
        self._check_nc(raw.shape[1])
        return raw

    def detect(self, frames) -> list[Detections]:
        """Detections of each (H, W, 3) uint8 RGB frame (frames may differ in size)."""
        frames = list(frames)
        results: list[Detections] = []
        for i in range(0, len(frames), self.batch):
            chunk = frames[i:i + self.batch]
            boxed = [letterbox(np.asarray(f), self.input_hw) for f in chunk]
            raw = self.run_raw(np.stack([b[0] for b in boxed]))
            dets = postprocess(raw, self.conf, self.iou, self.max_det)
            for d, (_, lb), frame in zip(dets, boxed, chunk, strict=True):
                img = lb.boxes_to_image(d)
                if self.classifier is not None and len(img):
                    top = img[:self.classify_top].copy()
                    pil = frame_image(frame)  # once for every step
                    for _ in range(self.refine_steps if self.classifier.refines else 1):
                        probs, moved = self.classifier.predict(pil, top[:, :4])
                        if moved is not None:
                            top[:, :4] = moved
                    img = reclassify(top, probs, min_prob=CLASSIFIER_MIN_PROB,
                                     iou=self.iou, max_det=self.max_det)
                results.append(Detections(boxes=img[:, :4], scores=img[:, 4],
                                          class_ids=img[:, 5].astype(np.int64),
                                          names=self.names))
        return results


# ----------------------------------------------------------------------------- second stage
REFINE_STEPS = 1
"""How many times a refining box classifier moves each box by default (`YoloDetector`; each
step reads the crop of the box the step before moved to). On the detector's validation
recordings (our renders; mAP50 for boxes >= 24 px, 216 frames, the shipped stage) more
steps help: 1 step 0.921, 2 0.945, 3 0.956, 4 0.956, 5 0.958; on CARLA's own frames (the
other validation set) they hurt: vehicle AP50 >= 24 px 0.630, 0.629 (2), 0.601 (4), all
sizes 0.474, 0.429 (2), 0.371 (4); the stage before it fell from 0.607 to 0.499 with four.
The stage shipped since the evening of 2026-12-06 (twice the recordings, 8 epochs; mirrored,
0.05): validation 0.933 (1 step), 0.970 (4); CARLA's frames 0.682 (1), 0.626 (4); held out
0.943 (1), 0.953 (4). One step is the default; ``--refine-steps 4`` suits the built-in
world's renders."""

CLASSIFIER_FLIP = True
"""Whether the box classifier reads each crop mirrored too by default (`BoxClassifier`'s
``flip``). Chosen on the two validation sets with one refining step: the detector's
validation recordings, mAP50 >= 24 px 0.921 -> 0.932 (two steps 0.945 -> 0.952, four 0.956
-> 0.954); CARLA's frames, vehicle AP50 >= 24 px 0.630 -> 0.655, all sizes 0.474 -> 0.500.
It costs one more batch through the network per step, not another crop
(`bench/bench_detector.py`, 9 boxes a frame: one step 26.0 -> 26.9 ms in one run, within
the noise in another; four steps 48.2 -> 55.0 ms). Held out, scored once: one step 0.921 ->
0.927, four 0.934 -> 0.947."""

CLASSIFIER_MIN_PROB = 0.05
"""`reclassify`'s ``min_prob`` in `YoloDetector`: a box is kept once for every class the
box classifier gives at least this probability (its most probable class always), each
scored detector score x probability, so a box whose side the stage cannot tell (a vehicle
near 45 degrees) is kept under both readings and each class's ranking finds it. Chosen
on the two validation sets (2026-12-06; 0.1 before): the detector's validation
recordings, mAP50 >= 24 px with the mirrored reading 0.932 -> 0.933 (one step), 0.952 ->
0.953 (two), 0.954 -> 0.959 (four; 0.02 gave the same, 0.959); CARLA's frames, vehicle AP50
>= 24 px 0.655 -> 0.655 (one step), all sizes 0.500 -> 0.500. The extra readings score at
most 0.1 x the detector's score: under perceive's default 0.25, they never reach the
tracker. Held out, scored once with it: one step 0.927 (unchanged), four 0.947 -> 0.949."""

CLASSIFIER_FILE = "classifier.onnx"
"""The shipped box classifier, beside the shipped detector (`default_classifier_path`)."""


def default_classifier_path(name: str = "shipped") -> Path:
    """The box classifier shipped beside a shipped detector (``SHIPPED_DETECTORS``)."""
    return default_model_path(name).parent / CLASSIFIER_FILE


CROP_REDUCING_GAP = 2.0
"""`box_crops`' Pillow ``reducing_gap``: a box much larger than the crop is first shrunk by
an integer factor (box averaging), then resampled, at least twice the crop's size; 1.6×
as fast as resampling it whole (9 boxes a frame: 6.3 → 3.8 ms), pixels 0.27 grey
levels apart on average, the refining stage's validation mAP50 >= 24 px unchanged
(0.9486 → 0.9491 with four steps)."""


def frame_image(rgb):
    """The Pillow image of an (H, W, 3) uint8 frame (a Pillow image passes through): what
    `box_crops` crops from, made once by a caller that crops one frame many times."""
    from PIL import Image

    return rgb if isinstance(rgb, Image.Image) else Image.fromarray(np.asarray(rgb, np.uint8))


_CROP_POOL: dict = {}
"""`box_crops`' thread pools by thread count, each with the process id it was made in (a
pool inherited through fork has no threads in the child: a new one is made there)."""


def _crop_pool(threads: int):
    import os
    from concurrent.futures import ThreadPoolExecutor

    pid, pool = _CROP_POOL.get(threads, (None, None))
    if pid != os.getpid():
        pool = ThreadPoolExecutor(threads, thread_name_prefix="dashtraj-crops")
        _CROP_POOL[threads] = (os.getpid(), pool)
    return pool


def box_crops(rgb, boxes: np.ndarray, margin: float, crop_px: int,
              input_px: int, threads: int = 1) -> np.ndarray:
    """(K, input_px, input_px, 3) uint8 crops of boxes (x0, y0, x1, y1, frame pixels): each
    box grown by ``margin`` of its width and height on every side (black beyond the frame),
    squashed to ``crop_px`` square (bilinear, ``CROP_REDUCING_GAP``), and its centre
    ``input_px`` square kept. ``rgb``: the (H, W, 3) uint8 frame or its `frame_image` (a
    caller cropping one frame many times makes that once). ``threads`` > 1: the boxes are
    cropped in that many threads (Pillow lets go of the GIL while it crops and resamples;
    the same bytes). The box classifier's training crops (`dashtraj.train.box_classifier`)
    are made the same way, the centre then drawn at random."""
    from itertools import pairwise

    from PIL import Image

    img = frame_image(rgb)
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    o = (crop_px - input_px) // 2
    out = np.zeros((len(boxes), input_px, input_px, 3), np.uint8)

    def crop(lo: int, hi: int) -> None:
        for k in range(lo, hi):
            x0, y0, x1, y1 = boxes[k]
            w, h = x1 - x0, y1 - y0
            box = tuple(round(float(v)) for v in (x0 - margin * w, y0 - margin * h,
                                                  x1 + margin * w, y1 + margin * h))
            if box[2] <= box[0] or box[3] <= box[1]:
                continue
            c = np.asarray(img.crop(box).resize((crop_px, crop_px), Image.BILINEAR,
                                                reducing_gap=CROP_REDUCING_GAP))
            out[k] = c[o:o + input_px, o:o + input_px]

    parts = min(max(1, int(threads)), len(boxes))
    if parts < 2:
        crop(0, len(boxes))
        return out
    cut = np.linspace(0, len(boxes), parts + 1).round().astype(int)
    for f in [_crop_pool(parts).submit(crop, int(a), int(b)) for a, b in pairwise(cut)]:
        f.result()
    return out


class BoxClassifier:
    """The detector's second stage: a crop classifier that reads each box's class and
    orientation from the frame's pixels (`dashtraj.train.box_classifier` trains it); a
    refining one also tells vehicles from background and moves each box's sides.

    Args:
        model: its ONNX file (input ``images`` (N, 3, S, S) RGB, /255, ImageNet mean/std;
            output ``logits`` (N, C), or (N, C + 1) with background last and metadata
            ``background`` "1"; optional output ``deltas`` (N, 4): the box's x0, y0, x1,
            y1 moves in box widths / heights; metadata ``names``, ``crop_px``,
            ``input_px``, ``margin``). threads: onnxruntime intra-op threads, and the
            threads that cut the crops (`box_crops`).
        flip: test-time augmentation: each crop is read mirrored left-right too, and the
            two readings averaged (probabilities; deltas with x0 and x1 swapped back).
            A mirror keeps a box's class (front, back and side stay what they are), and
            the stage trained on mirrored views. Default `CLASSIFIER_FLIP`.

    Raises:
        DetectorError: an unreadable model or one without that metadata.
    """

    def __init__(self, model=None, threads: int = 2, flip: bool = CLASSIFIER_FLIP):
        import json

        self.flip = bool(flip)
        self.threads = max(1, int(threads))
        self.path = Path(model) if model is not None else default_classifier_path()
        if not self.path.is_file():
            raise DetectorError(f"{self.path}: no such classifier model file")
        self.session = _session(self.path, threads, spin=False)
        meta = self.session.get_modelmeta().custom_metadata_map
        try:
            self.names = tuple(json.loads(meta["names"]))
            self.crop_px, self.input_px = int(meta["crop_px"]), int(meta["input_px"])
            self.margin = float(meta["margin"])
        except (KeyError, ValueError) as exc:
            raise DetectorError(f"{self.path}: not a dashtraj box classifier (its metadata "
                                f"lacks {exc})") from exc
        self._input = self.session.get_inputs()[0].name
        outs = [o.name for o in self.session.get_outputs()]
        self.background = meta.get("background") == "1"
        self.refines = "deltas" in outs
        self._outputs = ["logits" if "logits" in outs else outs[0]] + \
            (["deltas"] if self.refines else [])
        width = self.session.get_outputs()[outs.index(self._outputs[0])].shape[1]
        if isinstance(width, int) and width != len(self.names) + self.background:
            raise DetectorError(f"{self.path}: {width} logits for {len(self.names)} names"
                                f"{' and background' if self.background else ''}")

    def predict(self, rgb, boxes: np.ndarray,
                batch: int = 64) -> tuple[np.ndarray, np.ndarray | None]:
        """The boxes' (x0, y0, x1, y1, frame pixels) class probabilities (K, C) in the frame
        ``rgb`` ((H, W, 3) uint8 or its `frame_image`): a softmax
        over the classes and, for a model with a background class, background, whose
        column is dropped (a box's classes then sum to 1 minus its background
        probability); and a refining model's boxes moved by its deltas, clipped to the
        frame (`refine_boxes`), else None."""
        boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
        img = frame_image(rgb)
        crops = box_crops(img, boxes, self.margin, self.crop_px, self.input_px,
                          self.threads)
        mean = np.array([0.485, 0.456, 0.406], np.float32)
        std = np.array([0.229, 0.224, 0.225], np.float32)
        out, deltas = [], []
        for i in range(0, len(crops), batch):
            x = ((crops[i:i + batch].astype(np.float32) / 255.0 - mean) / std)
            n = len(x)
            if self.flip:
                x = np.concatenate([x, x[:, :, ::-1]])
            res = self.session.run(self._outputs, {self._input: np.ascontiguousarray(
                x.transpose(0, 3, 1, 2))})
            logits = res[0].astype(np.float64)
            e = np.exp(logits - logits.max(1, keepdims=True))
            p = (e / e.sum(1, keepdims=True))[:, :len(self.names)]
            d = res[1].astype(np.float64) if self.refines else None
            if self.flip:  # the mirror's x0 move is the box's x1 move, negated
                p = (p[:n] + p[n:]) / 2.0
                if d is not None:
                    m = d[n:].copy()
                    m[:, [0, 2]] = -d[n:, [2, 0]]
                    d = (d[:n] + m) / 2.0
            out.append(p)
            if d is not None:
                deltas.append(d)
        probs = np.concatenate(out) if out else np.zeros((0, len(self.names)))
        if not self.refines:
            return probs, None
        d = np.concatenate(deltas) if deltas else np.zeros((0, 4))
        return probs, refine_boxes(boxes, d, img.size)

    def probs(self, rgb: np.ndarray, boxes: np.ndarray, batch: int = 64) -> np.ndarray:
        """(K, C) class probabilities of the boxes (x0, y0, x1, y1, frame pixels)."""
        return self.predict(rgb, boxes, batch)[0]


def refine_boxes(boxes: np.ndarray, deltas: np.ndarray, size=None) -> np.ndarray:
    """Boxes (K, 4: x0, y0, x1, y1) with each side moved by its delta (K, 4) × the box's
    width (x) or height (y); clipped to a (width, height) frame when ``size`` is given,
    and never narrower than one pixel."""
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    wh = np.concatenate([boxes[:, 2:] - boxes[:, :2]] * 2, 1)
    out = boxes + np.asarray(deltas, np.float64).reshape(-1, 4) * wh
    if size is not None:
        out = np.clip(out, 0, [size[0], size[1], size[0], size[1]])
    out[:, 2:] = np.maximum(out[:, 2:], out[:, :2] + 1)
    return out


def reclassify(det: np.ndarray, probs: np.ndarray, min_prob: float = 0.1,
               iou: float = 0.6, max_det: int = 300) -> np.ndarray:
    """A frame's detector boxes (K, 6) [x0, y0, x1, y1, score, class] given their classes
    by the box classifier: each box once per class of probability ≥ ``min_prob`` (its most
    probable always), scored detector score × probability, then class-aware NMS at
    ``iou``; best first, at most ``max_det``."""
    det = np.asarray(det, np.float64).reshape(-1, 6)
    if not len(det):
        return det
    probs = np.asarray(probs, np.float64)
    take = probs >= min_prob
    take[np.arange(len(det)), probs.argmax(1)] = True
    i, c = np.nonzero(take)  # box by box, classes ascending
    out = np.column_stack([det[i, :4], det[i, 4] * probs[i, c], c]).astype(np.float64)
    keep = nms(out[:, :4], out[:, 4], iou, out[:, 5], max_keep=max_det)
    return out[keep]
