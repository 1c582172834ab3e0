"""Detection metrics: COCO-style AP (101-point interpolation) per class, mAP50, mAP50-95,
and precision/recall at an operating threshold.

Protocol (pycocotools' ``COCOeval.evaluate``/``accumulate`` for bounding boxes, one
area range, at most ``max_det`` detections per image):

- per image and class, detections sorted by score are matched greedily to the
  unmatched ground truth of highest IoU ≥ t (IoU without the +1 pixel convention);
  non-ignored ground truths are preferred over ignored ones;
- a size range (here: ground-truth box *height* ≥ ``min_height_px``) marks ground
  truths outside it "ignored": a detection matched to one, or an unmatched detection
  outside the range, counts neither as true nor as false positive;
- per class and IoU threshold t ∈ {0.50, 0.55, …, 0.95}: cumulative TP/FP over all
  images in score order, precision made monotone from the right, sampled at 101
  recall points 0, 0.01, …, 1 (0 where the recall is never reached); AP = the mean;
- classes without ground truth (in the range) get no AP and are left out of the mean.

Checked against pycocotools in ``tests/perception/test_detmetrics.py``.
"""

from __future__ import annotations

import numpy as np

IOU_THRESHOLDS = np.linspace(0.5, 0.95, 10)
RECALL_POINTS = np.linspace(0.0, 1.0, 101)


def _iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    from dashtraj.perception.detect import box_iou

    return box_iou(a, b)


def _match_image(det: np.ndarray, gt: np.ndarray, gt_ignore: np.ndarray, det_small: np.ndarray,
                 thresholds: np.ndarray):
    """Match one image's detections of one class (sorted by score) for every threshold.

    Returns (T, D) matched flags and (T, D) ignore flags.
    """
    t, d = len(thresholds), len(det)
    matched = np.zeros((t, d), bool)
    ignored = np.zeros((t, d), bool)
    if d == 0:
        return matched, ignored
    if len(gt) == 0:
        ignored[:] = det_small[None, :]
        return matched, ignored
    # ground truths: non-ignored first (pycocotools sorts them so)
    g_order = np.argsort(gt_ignore, kind="stable")
    gt, gt_ignore = gt[g_order], gt_ignore[g_order]
    ious = _iou(det[:, :4], gt[:, :4])
    for ti, thr in enumerate(thresholds):
        used = np.zeros(len(gt), bool)
        for di in range(d):
            best, m = min(thr, 1 - 1e-10), -1
            for gi in range(len(gt)):
                if used[gi]:
                    continue
                # once a real match is found, stop at the first ignored ground truth
                if m > -1 and not gt_ignore[m] and gt_ignore[gi]:
                    break
                if ious[di, gi] < best:
                    continue
                best, m = ious[di, gi], gi
            if m == -1:
                ignored[ti, di] = det_small[di]
                continue
            used[m] = True
            matched[ti, di] = True
            ignored[ti, di] = gt_ignore[m]
    return matched, ignored


def average_precision(tp: np.ndarray, fp: np.ndarray, n_pos: int) -> float:
    """101-point interpolated AP of detections in descending score order.

    Args:
        tp, fp: (D,) bool, true/false positive flags (ignored detections removed).
        n_pos: ground truths to find.
    """
    if n_pos == 0:
        return float("nan")
    tpc = np.cumsum(tp, dtype=np.float64)
    fpc = np.cumsum(fp, dtype=np.float64)
    rec = tpc / n_pos
    prec = tpc / np.maximum(tpc + fpc, np.finfo(np.float64).eps)
    prec = np.maximum.accumulate(prec[::-1])[::-1] if len(prec) else prec
    idx = np.searchsorted(rec, RECALL_POINTS, side="left")
    q = np.zeros(len(RECALL_POINTS))
    ok = idx < len(prec)
    q[ok] = prec[idx[ok]]
    return float(np.mean(q))


def evaluate_detections(preds, gts, num_classes: int, names=None,
                        min_height_px: float = 0.0, small_px: float | None = 24.0,
                        conf: float = 0.25, max_det: int = 100) -> dict:
    """Score detections against ground truth.

    Args:
        preds: per image an (K, 6) array [x0, y0, x1, y1, score, class] (pixels).
        gts: per image an (M, 5) array [x0, y0, x1, y1, class] (same pixels), or (M, 6)
            with a last column ``ignore`` (1: an ignore region, as COCO's crowd boxes
            but matched by plain IoU).
        num_classes: class count; names: their names (default "0", "1", ...).
        min_height_px: the size range of the main figures (0 = all boxes).
        small_px: also report ``*_24px`` figures for boxes at least this tall
            (None: skip).
        conf: score threshold of the precision/recall figures (IoU 0.5).
        max_det: detections kept per image (highest scores), as COCO's maxDets.

    Returns:
        dict with ``map50``, ``map50_95``, ``precision``, ``recall``, ``per_class``
        ({name: {"ap50", "ap50_95", "gt"}} for classes with ground truth), ``gt`` count,
        and the same figures for boxes ≥ ``small_px`` under keys suffixed ``_24px``
        (``per_class_24px`` etc.).
    """
    names = list(names) if names is not None else [str(i) for i in range(num_classes)]
    res = _evaluate(preds, gts, num_classes, names, min_height_px, conf, max_det)
    if small_px is not None:
        sub = _evaluate(preds, gts, num_classes, names, small_px, conf, max_det)
        for k, v in sub.items():
            res[f"{k}_24px"] = v
        res["small_px"] = small_px
    return res


def _evaluate(preds, gts, nc, names, min_h, conf, max_det) -> dict:
    thr = IOU_THRESHOLDS
    per_cls_scores: list[list[np.ndarray]] = [[] for _ in range(nc)]
    per_cls_match: list[list[np.ndarray]] = [[] for _ in range(nc)]
    per_cls_ign: list[list[np.ndarray]] = [[] for _ in range(nc)]
    n_pos = np.zeros(nc, np.int64)
    tp50 = fp50 = 0
    for det, gt in zip(preds, gts, strict=True):
        det = np.asarray(det, np.float64).reshape(-1, 6)
        gt = np.asarray(gt, np.float64)
        gt = gt.reshape(-1, gt.shape[-1] if gt.ndim == 2 else 5)
        if gt.shape[1] == 5:
            gt = np.concatenate([gt, np.zeros((len(gt), 1))], 1)
        det = det[np.argsort(-det[:, 4], kind="stable")][:max_det]
        for c in range(nc):
            dc = det[det[:, 5] == c]
            gc = gt[gt[:, 4] == c]
            g_ign = ((gc[:, 3] - gc[:, 1]) < min_h) | (gc[:, 5] > 0)
            n_pos[c] += int((~g_ign).sum())
            d_small = (dc[:, 3] - dc[:, 1]) < min_h
            m, ig = _match_image(dc, gc, g_ign, d_small, thr)
            per_cls_scores[c].append(dc[:, 4])
            per_cls_match[c].append(m)
            per_cls_ign[c].append(ig)
            keep = dc[:, 4] >= conf
            tp50 += int((m[0] & ~ig[0] & keep).sum())
            fp50 += int((~m[0] & ~ig[0] & keep).sum())
    ap = np.full((nc, len(thr)), np.nan)
    for c in range(nc):
        if n_pos[c] == 0:
            continue
        s = np.concatenate(per_cls_scores[c]) if per_cls_scores[c] else np.zeros(0)
        m = np.concatenate(per_cls_match[c], 1) if per_cls_match[c] else np.zeros((10, 0), bool)
        ig = np.concatenate(per_cls_ign[c], 1) if per_cls_ign[c] else np.zeros((10, 0), bool)
        order = np.argsort(-s, kind="mergesort")
        for ti in range(len(thr)):
            mm, ii = m[ti, order], ig[ti, order]
            ap[c, ti] = average_precision(mm[~ii], ~mm[~ii], int(n_pos[c]))
    present = n_pos > 0
    total = int(n_pos.sum())
    return {
        "map50": float(np.mean(ap[present, 0])) if present.any() else float("nan"),
        "map50_95": float(np.mean(ap[present])) if present.any() else float("nan"),
        "precision": tp50 / (tp50 + fp50) if tp50 + fp50 else float("nan"),
        "recall": tp50 / total if total else float("nan"),
        "gt": total,
        "per_class": {names[c]: {"ap50": float(ap[c, 0]), "ap50_95": float(np.mean(ap[c])),
                                 "gt": int(n_pos[c])}
                      for c in range(nc) if present[c]},
    }
