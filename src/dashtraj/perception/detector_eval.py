"""Evaluate a detector on recordings' rendered frames against the renderer's exact boxes.

Ground truth per frame: every vehicle with visible pixels, its *visible* box
(``VehicleLabel.visible_box``, frame pixels) and detection class. Vehicles the detection
set leaves unlabelled (visible box lower than ``min_box_height_px`` or occlusion above
``max_occlusion``, `dashtraj.datasets.detection`) are *ignore* regions: a detection on
one counts neither as true nor as false positive (COCO's crowd/area-range rule), so the
all-size figures neither reward nor punish finding them. Scores: `evaluate_detections`
(COCO 101-point AP, mAP50, mAP50-95, P/R at the detector's threshold), all sizes and
boxes at least ``small_px`` tall (24 px at 1280×720: vehicles within about 30 m).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class EvalConfig:
    """every_s: sampling period, seconds. size: (W, H) frame size or None for the
    recordings' camera. min_box_height_px / max_occlusion: the detection set's label
    filters scaled to the frame (10 px at 640×360 = 20 px at 1280×720). small_px: the
    size subset. conf: operating threshold of P/R. batch: frames per detector run."""

    every_s: float = 2.0
    size: tuple[int, int] | None = None
    min_box_height_px: float = 20.0
    max_occlusion: float = 0.7
    small_px: float = 24.0
    conf: float = 0.25
    batch: int = 8


def frame_ground_truth(labels, min_box_height_px: float, max_occlusion: float) -> np.ndarray:
    """(M, 6) [x0, y0, x1, y1, class, ignore] of one frame's visible vehicles, pixels."""
    rows = []
    for lab in labels:
        b = lab.visible_box
        if b is None or lab.visible_pixels <= 0:
            continue
        ignore = (b[3] - b[1] < min_box_height_px) or (1 - lab.visible_fraction > max_occlusion)
        rows.append([*map(float, b), float(lab.detection_class_id), float(ignore)])
    return np.array(rows, np.float64).reshape(-1, 6)


def evaluate_recordings(recordings, detector, config: EvalConfig = EvalConfig(),
                        progress=None) -> dict:
    """Render, detect and score; returns the `evaluate_detections` dict plus
    ``frames``, ``recordings``, ``model``, ``config`` and ``class_counts`` (labelled
    ground truths per class)."""
    from dataclasses import asdict

    from dashtraj.datasets.frames import recording_frames
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

        for rf in recording_frames(rec, config.every_s, config.size):
            buf_rgb.append(rf.frame_data.rgb)
            buf_gt.append(frame_ground_truth(rf.frame_data.labels, config.min_box_height_px,
                                             config.max_occlusion))
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
