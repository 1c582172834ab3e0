"""Our COCO-style mAP against pycocotools (the reference implementation) on the same boxes."""

import numpy as np
import pytest

from dashtraj.perception.detmetrics import average_precision, evaluate_detections


def _random_case(rng, n_img=25, nc=4):
    preds, gts = [], []
    for _ in range(n_img):
        m = int(rng.integers(0, 7))
        xy = rng.uniform(0, 500, (m, 2))
        wh = rng.uniform(8, 120, (m, 2))
        g = np.concatenate([xy, xy + wh, rng.integers(0, nc, (m, 1))], 1)
        dets = []
        for row in g:  # a jittered detection per ground truth (sometimes the wrong class)
            if rng.random() < 0.85:
                jit = rng.normal(0, 0.12, 4) * np.r_[row[2] - row[0], row[3] - row[1]] \
                    .repeat(2)[[0, 2, 1, 3]]
                c = row[4] if rng.random() < 0.85 else rng.integers(0, nc)
                dets.append([*(row[:4] + jit), rng.uniform(0.05, 1.0), c])
        for _ in range(int(rng.integers(0, 4))):  # false positives
            p = rng.uniform(0, 500, 2)
            s = rng.uniform(8, 100, 2)
            dets.append([*p, *(p + s), rng.uniform(0.0, 0.7), rng.integers(0, nc)])
        d = np.array(dets, float).reshape(-1, 6)
        d[:, [2, 3]] = np.maximum(d[:, [2, 3]], d[:, [0, 1]] + 1)
        preds.append(d)
        gts.append(g)
    return preds, gts


def _coco(preds, gts, nc):
    pytest.importorskip("pycocotools")
    from pycocotools.coco import COCO
    from pycocotools.cocoeval import COCOeval

    images, anns, results = [], [], []
    for i, (d, g) in enumerate(zip(preds, gts, strict=True)):
        images.append({"id": i, "width": 640, "height": 640})
        for r in g:
            anns.append({"id": len(anns) + 1, "image_id": i, "category_id": int(r[4]),
                         "bbox": [r[0], r[1], r[2] - r[0], r[3] - r[1]],
                         "area": (r[2] - r[0]) * (r[3] - r[1]), "iscrowd": 0})
        for r in d:
            results.append({"image_id": i, "category_id": int(r[5]),
                            "bbox": [r[0], r[1], r[2] - r[0], r[3] - r[1]], "score": r[4]})
    gt = COCO()
    gt.dataset = {"images": images, "annotations": anns,
                  "categories": [{"id": c} for c in range(nc)]}
    gt.createIndex()
    dt = gt.loadRes(results)
    ev = COCOeval(gt, dt, "bbox")
    ev.evaluate()
    ev.accumulate()
    prec = ev.eval["precision"][:, :, :, 0, -1]  # T, R, K at area 'all', maxDets 100
    per_class = {}
    for k in range(nc):
        p = prec[:, :, k]
        if (p > -1).any():
            per_class[k] = (float(p[0].mean()), float(p.mean()))
    valid = prec[0] > -1
    return float(prec[0][valid].mean()), float(prec[prec > -1].mean()), per_class


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_map_matches_pycocotools(seed):
    rng = np.random.default_rng(seed)
    preds, gts = _random_case(rng)
    ours = evaluate_detections(preds, gts, 4, small_px=None)
    m50, m5095, per = _coco(preds, gts, 4)
    assert 0.2 < ours["map50"] < 1.0  # a non-trivial case
    assert ours["map50"] == pytest.approx(m50, abs=1e-9)
    assert ours["map50_95"] == pytest.approx(m5095, abs=1e-9)
    for k, (a50, a5095) in per.items():
        assert ours["per_class"][str(k)]["ap50"] == pytest.approx(a50, abs=1e-9)
        assert ours["per_class"][str(k)]["ap50_95"] == pytest.approx(a5095, abs=1e-9)


def test_perfect_detections_score_one_and_ignores_do_not_count():
    g = np.array([[10, 10, 60, 40, 0], [100, 100, 110, 108, 1]], float)
    d = np.array([[10, 10, 60, 40, 0.9, 0], [100, 100, 110, 108, 0.8, 1]], float)
    r = evaluate_detections([d], [g], 2, small_px=24)
    assert r["map50"] == 1.0 and r["map50_95"] == 1.0
    assert r["precision"] == 1.0 and r["recall"] == 1.0
    # the 8 px tall box is out of the >= 24 px subset: its detection is ignored, not an FP
    assert r["gt_24px"] == 1 and r["map50_24px"] == 1.0 and r["precision_24px"] == 1.0
    # an ignore flag (6th column) makes a ground truth an ignore region
    g6 = np.concatenate([g, [[0], [1]]], 1)
    r6 = evaluate_detections([d], [g6], 2, small_px=None)
    assert r6["gt"] == 1 and r6["precision"] == 1.0 and list(r6["per_class"]) == ["0"]


def test_average_precision_101_points():
    # one TP then one FP, 2 ground truths: recall 0.5 reached at precision 1
    ap = average_precision(np.array([True, False]), np.array([False, True]), 2)
    assert ap == pytest.approx(51 / 101)


def test_ground_truth_ignores_slivers_beyond_the_frame_edge():
    """KITTI's truncation rule: a vehicle mostly outside the frame (here a 7 px wide strip
    at the right edge, 93 % of its silhouette beyond it) is an ignore region, so missing
    it costs no recall; half inside still counts. max_truncation 1 keeps the old rule."""
    from types import SimpleNamespace

    from dashtraj.perception.detector_eval import EvalConfig, frame_ground_truth

    def lab(box, cls, vis=1.0, trunc=0.0):
        return SimpleNamespace(visible_box=box, visible_pixels=100, visible_fraction=vis,
                               truncation=trunc, detection_class_id=cls)

    labels = [lab((100, 300, 300, 420), 1), lab((1273, 375, 1280, 417), 12, trunc=0.93),
              lab((0, 300, 90, 400), 2, trunc=0.45), lab((500, 300, 600, 390), 0, vis=0.2),
              lab((700, 350, 720, 365), 3), lab((800, 350, 900, 420), 4, trunc=0.51)]
    assert EvalConfig().max_truncation == 0.5
    g = frame_ground_truth(labels, 20.0, 0.7)
    assert g[:, 5].tolist() == [0, 1, 0, 1, 1, 1]
    assert g[:, 4].tolist() == [1, 12, 2, 0, 3, 4]
    assert frame_ground_truth(labels, 20.0, 0.7, 1.0)[:, 5].tolist() == [0, 0, 0, 1, 1, 0]
    # the two labelled boxes found, the sliver and the 51 % truncated one missed
    d = np.array([[100, 300, 300, 420, 0.9, 1], [0, 300, 90, 400, 0.8, 2]], float)
    assert evaluate_detections([d], [g], 15, small_px=24)["recall"] == 1.0
    old = evaluate_detections([d], [frame_ground_truth(labels, 20.0, 0.7, 1.0)], 15,
                              small_px=24)
    assert old["recall"] == 0.5 and old["gt"] == 4
