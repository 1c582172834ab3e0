"""Evaluate a detector on recordings' rendered frames against the renderer's exact boxes
(or on a drive's images against its truth boxes: `dashtraj.datasets.drive_truth`).

Ground truth per frame: every vehicle with visible pixels, its *visible* box
(``VehicleLabel.visible_box``, frame pixels) and detection class. Vehicles the detection
set leaves unlabelled (visible box lower than ``min_box_height_px`` or occlusion above
``max_occlusion``, `dashtraj.datasets.detection`) and vehicles mostly outside the frame
(``truncation`` above ``max_truncation``: KITTI's rule, whose hardest level keeps objects
truncated up to 50 %; a car 95 % beyond the frame's edge is a sliver a few pixels wide) are
*ignore* regions: a detection on one counts neither as true nor as false positive (COCO's
crowd/area-range rule), so the figures neither reward nor punish finding them.
Scores: `evaluate_detections` (COCO 101-point AP, mAP50, mAP50-95, P/R at the detector's
threshold), all sizes and boxes at least ``small_px`` tall (24 px at 1280×720: vehicles
within about 30 m).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class EvalConfig:
    """every_s: sampling period, seconds. size: (W, H) frame size or None for the
    recordings' camera. min_box_height_px / max_occlusion: the detection set's label
    filters scaled to the frame (10 px at 640×360 = 20 px at 1280×720). max_truncation:
    vehicles with a larger share of their projected silhouette outside the frame are
    ignored (KITTI's hard level, 0.5; 1 ignores none: the rule before 2026-12-06). small_px: the
    size subset. conf: operating threshold of P/R. batch: frames per detector run."""

    every_s: float = 2.0
    size: tuple[int, int] | None = None
    min_box_height_px: float = 20.0
    max_occlusion: float = 0.7
    max_truncation: float = 0.5
    small_px: float = 24.0
    conf: float = 0.25
    batch: int = 8


def frame_ground_truth(labels, min_box_height_px: float, max_occlusion: float,
                       max_truncation: float = 0.5) -> np.ndarray:
    """(M, 6) [x0, y0, x1, y1, class, ignore] of one frame's visible vehicles, pixels;
    ignored: lower than ``min_box_height_px``, more occluded than ``max_occlusion`` or
    more truncated by the frame's edges than ``max_truncation`` (`EvalConfig`)."""
    rows = []
    for lab in labels:
        b = lab.visible_box
        if b is None or lab.visible_pixels <= 0:
            continue
        ignore = (b[3] - b[1] < min_box_height_px or 1 - lab.visible_fraction > max_occlusion
                  or lab.truncation > max_truncation)
        rows.append([*map(float, b), float(lab.detection_class_id), float(ignore)])
    return np.array(rows, np.float64).reshape(-1, 6)


def evaluate_recordings(recordings, detector, config: EvalConfig = EvalConfig(),
                        progress=None) -> dict:
    """Render, detect and score; returns the `evaluate_detections` dict plus
    ``frames``, ``recordings``, ``model``, ``config`` and ``class_counts`` (labelled
    ground truths per class)."""
    from dataclasses import asdict

    from dashtraj.datasets.frames import source_frames
    from dashtraj.perception.detmetrics import evaluate_detections

    preds, gts = [], []
    names = list(detector.names)
    for rec in recordings:
        buf_rgb, buf_gt = [], []

        def flush(buf_rgb=buf_rgb, buf_gt=buf_gt):
            for d, g in zip(detector.detect(buf_rgb), buf_gt, strict=True):
                preds.append(np.concatenate([d.boxes, d.scores[:, None],
                                             d.class_ids[:, None].astype(np.float64)], 1))
                gts.append(g)
            buf_rgb.clear()
            buf_gt.clear()

        for rf in source_frames(rec, config.every_s, config.size):
            buf_rgb.append(rf.frame_data.rgb)
            buf_gt.append(frame_ground_truth(rf.frame_data.labels, config.min_box_height_px,
                                             config.max_occlusion, config.max_truncation))
            if progress is not None:
                progress()
            if len(buf_rgb) >= config.batch:
                flush()
        if buf_rgb:
            flush()
    res = evaluate_detections(preds, gts, len(names), names=names, small_px=config.small_px,
                              conf=config.conf)
    counts = np.zeros(len(names), np.int64)
    for g in gts:
        for c in g[g[:, 5] == 0, 4].astype(int):
            counts[c] += 1
    res.update({"frames": len(gts), "recordings": [str(r.path) for r in recordings],
                "model": str(detector.path),
                "config": {**asdict(config), "size": list(config.size) if config.size else None},
                "class_counts": {n: int(c) for n, c in zip(names, counts, strict=True)}})
    return res


def plot_per_class(result: dict, path) -> None:
    """Bar chart of AP50 per class, all boxes and boxes ≥ small_px (as the paper's Fig. 5)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(result["class_counts"])
    all_ap = [result["per_class"].get(n, {}).get("ap50", np.nan) for n in names]
    big_ap = [result.get("per_class_24px", {}).get(n, {}).get("ap50", np.nan) for n in names]
    x = np.arange(len(names))
    fig, ax = plt.subplots(figsize=(11, 4))
    ax.bar(x - 0.2, all_ap, 0.4, label=f"all boxes (mAP50 {result['map50']:.3f})")
    if "map50_24px" in result:
        ax.bar(x + 0.2, big_ap, 0.4,
               label=f">= {result.get('small_px', 24):g} px (mAP50 {result['map50_24px']:.3f})")
    ax.set_xticks(x, names, rotation=45, ha="right")
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("AP50")
    ax.set_title(f"vehicle detection AP per class on {result['frames']} held-out frames")
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# --------------------------------------------------------------- another source's frames
# ours -> theirs by the base class of our 15 names ("car_front" -> "car"): the mapping of
# the CARLA Object Detection Dataset (../shared/carla_frames) and of most road sets.
DEFAULT_CLASS_MAP = {"car": "vehicle", "truck": "vehicle", "bus": "vehicle",
                     "motorcycle": "motobike", "bicycle": "bike"}


def parse_class_map(text: str) -> dict[str, str]:
    """``car=vehicle,truck=vehicle,...`` -> {ours: theirs}; ValueError names the bad item."""
    out = {}
    for item in text.split(","):
        if not item.strip():
            continue
        a, sep, b = item.partition("=")
        if not sep or not a.strip() or not b.strip():
            raise ValueError(f"{item!r} is not OURS=THEIRS")
        out[a.strip()] = b.strip()
    if not out:
        raise ValueError("empty class map")
    return out


def read_external_names(folder) -> list[str] | None:
    """Class names of a YOLO folder: data.yaml ``names`` or classes.txt/obj.names (one
    per line); None when it has neither."""
    from pathlib import Path

    from dashtraj.errors import read_utf8
    from dashtraj.perception.detect import read_names_yaml

    folder = Path(folder)
    for y in ("data.yaml", "dataset.yaml"):
        if (folder / y).is_file():
            return read_names_yaml(folder / y)
    for t in ("classes.txt", "obj.names"):
        if (folder / t).is_file():
            return [ln.strip() for ln in read_utf8(folder / t).splitlines() if ln.strip()]
    return None


def read_external_set(folder, num_classes: int) -> list[tuple[object, np.ndarray]]:
    """(image path, (M, 5) float [class, cx, cy, w, h] normalised) of every image in
    ``folder/images`` (or ``folder`` itself), labels from ``folder/labels/NAME.txt``
    beside them; an image without a label file has no objects.

    Raises:
        DashtrajError: no images, or a label line that is not ``class cx cy w h`` with a
        class id below ``num_classes`` and finite coordinates (names file:line).
    """
    from pathlib import Path

    from dashtraj.errors import DashtrajError, read_utf8

    folder = Path(folder)
    img_dir = folder / "images" if (folder / "images").is_dir() else folder
    lab_dir = folder / "labels" if (folder / "labels").is_dir() else img_dir
    suffixes = (".jpg", ".jpeg", ".png", ".bmp")
    imgs = sorted(p for p in img_dir.rglob("*") if p.suffix.lower() in suffixes)
    if not imgs:
        raise DashtrajError(f"{folder}: no images ({', '.join(suffixes)}) in {img_dir}")
    out = []
    for p in imgs:
        lab = lab_dir / p.relative_to(img_dir).with_suffix(".txt")
        rows = []
        if lab.is_file():
            for i, line in enumerate(read_utf8(lab).splitlines(), 1):
                vals = line.split()
                if not vals:
                    continue
                try:
                    row = [float(v) for v in vals]
                except ValueError:
                    row = []
                if (len(row) != 5 or not np.all(np.isfinite(row)) or row[0] != int(row[0])
                        or not 0 <= row[0] < num_classes or min(row[3], row[4]) < 0
                        or not all(-0.01 <= v <= 1.01 for v in row[1:])):
                    raise DashtrajError(f"{lab}:{i}: expected 'class cx cy w h' with a class "
                                        f"id 0..{num_classes - 1} and cx, cy, w, h normalised "
                                        f"to 0..1, got {line.strip()!r}")
                rows.append(row)
        out.append((p, np.array(rows, np.float64).reshape(-1, 5)))
    return out


def evaluate_external(folder, detector, their_names, class_map=None, small_px: float = 24.0,
                      conf: float = 0.25, iou: float = 0.6, max_images: int | None = None,
                      progress=None) -> dict:
    """Score our detector on another source's frames with YOLO labels.

    Each of our detections takes the class ``class_map[base]`` (default
    `DEFAULT_CLASS_MAP`, restricted to the classes the set has) (``base``: our name
    without its ``_front``/``_back``/``_side`` orientation); detections whose base is
    unmapped are dropped, and after the mapping a class-aware NMS (IoU ``iou``) keeps
    one box per object. Their classes that no class of ours maps to (traffic lights,
    signs) are not scored. Figures: AP50 / AP50-95 per mapped class (all boxes and
    boxes at least ``small_px`` tall, in the frames' own pixels), and the headline
    ``vehicle`` (their first mapped class of car/truck/bus), plus class-agnostic
    ``any`` (every detection against every scored ground truth).

    Returns:
        a dict: ``images``, ``model``, ``names`` (theirs), ``class_map``, ``per_class``
        and ``per_class_24px`` ({their name: {ap50, ap50_95, gt}}), ``map50`` (mean over
        the scored classes), ``vehicle_ap50``, ``vehicle_ap50_24px``, ``any_ap50``,
        ``any_ap50_24px``, precision/recall at ``conf``.
    """
    from dashtraj.errors import DashtrajError
    from dashtraj.perception.detect import nms, read_rgb
    from dashtraj.perception.detmetrics import evaluate_detections
    from dashtraj.trajectory.records import ORIENTATIONS

    their_names = list(their_names)
    if class_map is None:  # the default map, restricted to the classes the set has
        class_map = {o: t for o, t in DEFAULT_CLASS_MAP.items() if t in their_names}
        if not class_map:
            raise DashtrajError(f"none of {', '.join(sorted(set(DEFAULT_CLASS_MAP.values())))} "
                                f"is a class of the set ({', '.join(their_names)}); pass a "
                                "class map (OURS=THEIRS,...)")
    class_map = dict(class_map)
    # our base class of each model class ("car_front" -> "car"; a name without an
    # orientation suffix is its own base)
    base = [n.rsplit("_", 1)[0] if n.rsplit("_", 1)[-1] in ORIENTATIONS else n
            for n in detector.names]
    bases = sorted(set(base))
    for o, t in class_map.items():
        if o not in bases:
            raise DashtrajError(f"class map: {o!r} is not a class of the model "
                                f"({', '.join(bases)})")
        if t not in their_names:
            raise DashtrajError(f"class map: {t!r} is not a class of the set "
                                f"({', '.join(their_names)})")
    scored = [t for t in their_names if t in class_map.values()]
    our_to_scored = np.array([scored.index(class_map[b]) if b in class_map else -1
                              for b in base], np.int64)
    their_to_scored = np.array([scored.index(t) if t in scored else -1 for t in their_names])
    items = read_external_set(folder, len(their_names))[:max_images]
    preds, preds_any, gts, gts_any = [], [], [], []
    for start in range(0, len(items), 8):
        chunk = items[start:start + 8]
        rgbs = [read_rgb(p) for p, _ in chunk]
        for d, rgb, (_, lab) in zip(detector.detect(rgbs), rgbs, chunk, strict=True):
            h, w = rgb.shape[:2]
            c = our_to_scored[d.class_ids] if len(d) else np.zeros(0, np.int64)
            m = c >= 0
            b, s, c = d.boxes[m], d.scores[m], c[m]
            k = nms(b, s, iou, classes=c)  # one box per object after the mapping
            b, s, c = b[k], s[k], c[k]
            preds.append(np.concatenate([b, s[:, None], c[:, None].astype(np.float64)], 1))
            ka = nms(b, s, iou)
            preds_any.append(np.concatenate([b[ka], s[ka, None], np.zeros((len(ka), 1))], 1))
            tc = their_to_scored[lab[:, 0].astype(np.int64)] if len(lab) else np.zeros(0, int)
            lab = lab[tc >= 0]
            tc = tc[tc >= 0]
            xyxy = np.stack([(lab[:, 1] - lab[:, 3] / 2) * w, (lab[:, 2] - lab[:, 4] / 2) * h,
                             (lab[:, 1] + lab[:, 3] / 2) * w, (lab[:, 2] + lab[:, 4] / 2) * h],
                            1) if len(lab) else np.zeros((0, 4))
            gts.append(np.concatenate([xyxy, tc[:, None].astype(np.float64)], 1))
            gts_any.append(np.concatenate([xyxy, np.zeros((len(xyxy), 1))], 1))
            if progress is not None:
                progress()
    res = evaluate_detections(preds, gts, len(scored), names=scored, small_px=small_px,
                              conf=conf)
    agn = evaluate_detections(preds_any, gts_any, 1, names=["any"], small_px=small_px,
                              conf=conf)
    vehicle = next((class_map[b] for b in ("car", "truck", "bus") if b in class_map), scored[0])

    def ap(d, key):
        v = d.get(key, {}).get(vehicle)
        return v["ap50"] if v else float("nan")

    res.update({
        "images": len(items), "model": str(detector.path), "folder": str(folder),
        "names": their_names, "class_map": class_map, "scored_classes": scored,
        "vehicle_class": vehicle,
        "vehicle_ap50": ap(res, "per_class"), "vehicle_ap50_24px": ap(res, "per_class_24px"),
        "any_ap50": agn["map50"], "any_ap50_24px": agn.get("map50_24px", float("nan")),
        "any_precision": agn["precision"], "any_recall": agn["recall"],
        "conf": conf, "nms_iou": iou,
    })
    return res
