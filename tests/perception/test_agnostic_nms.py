"""Class-agnostic NMS of the detector model in the perception pipeline: one box per vehicle
instead of one per orientation class, the vehicles found unchanged."""

from __future__ import annotations

import numpy as np

from dashtraj.datasets.frames import recording_frames
from dashtraj.perception.detect import box_iou, default_model_path
from dashtraj.perception.detections import build_detector, iou_matrix, truth_of


def test_agnostic_nms_drops_duplicates_and_keeps_the_vehicles(small_run, gl_available):
    aware = build_detector(str(default_model_path()), threads=1)
    agnostic = build_detector(str(default_model_path()), threads=1, agnostic_iou=0.45)
    n_aware = n_agnostic = found_aware = found_agnostic = 0
    frames = recording_frames(small_run, 1.0, (640, 360), [1], msaa=0)
    for k, rf in enumerate(frames):
        if k >= 12:
            break
        a, g = aware.detect(rf), agnostic.detect(rf)
        n_aware += len(a)
        n_agnostic += len(g)
        # a subset of the class-aware boxes, none overlapping another by more than 0.45
        for b in g.boxes:
            assert np.any(np.all(np.isclose(a.boxes, b), axis=1))
        if len(g) > 1:
            iou = box_iou(g.boxes, g.boxes)
            np.fill_diagonal(iou, 0.0)
            assert iou.max() <= 0.45 + 1e-9
        t = truth_of(rf)
        for d, counter in ((a, "aware"), (g, "agnostic")):
            hit = int((iou_matrix(d.boxes, t.boxes).max(axis=0) >= 0.5).sum()) \
                if len(d) and len(t) else 0
            if counter == "aware":
                found_aware += hit
            else:
                found_agnostic += hit
    assert n_agnostic <= n_aware
    assert found_agnostic == found_aware  # every vehicle still has a box
