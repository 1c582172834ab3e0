"""`depicted_vehicles`: which vehicle a detection's box shows, from the renderer's instance
image (the ReID scoring's truth), on real rendered frames."""

from __future__ import annotations

import numpy as np

from dashtraj.datasets.frames import recording_frames
from dashtraj.perception.detections import depicted_vehicles, match_truth, truth_of


def test_duplicate_and_part_boxes_show_their_vehicle(small_run, gl_available):
    checked = grown = 0
    for rf in recording_frames(small_run, 1.0, (640, 360), [1, 3], msaa=0):
        truth = truth_of(rf, min_height_px=12.0, min_visible_fraction=0.5)
        if not len(truth):
            continue
        b = truth.boxes
        # each truth box shows its own vehicle
        assert depicted_vehicles(rf, b).tolist() == truth.truth_ids.tolist()
        # a second, identical box of one vehicle: one to one matching leaves it
        # unmatched (-1), the pixels still say whose it is
        dup = np.vstack([b, b[:1]])
        assert match_truth(type(truth)(dup, np.ones(len(dup)), np.zeros(len(dup), np.int64),
                                       np.full(len(dup), -1)), truth)[-1] == -1
        assert depicted_vehicles(rf, dup)[-1] == truth.truth_ids[0]
        # the lower half of a mostly visible vehicle's box (a part box, IoU ~ 0.5 or less)
        half = b.copy()
        half[:, 1] = (b[:, 1] + b[:, 3]) / 2
        shown = depicted_vehicles(rf, half)
        assert (shown == truth.truth_ids).mean() >= 0.8
        checked += len(b)
        # a box three times as wide and high holding all of a vehicle and nothing else
        # (a thin motorcycle seen from behind fills a small part of its box) shows it
        inst = rf.frame_data.instance
        for (x0, y0, x1, y1), vid in zip(b, truth.truth_ids, strict=True):
            w, h = x1 - x0, y1 - y0
            big = np.array([[x0 - w, y0 - h, x1 + w, y1 + h]])
            if big[0, 0] < 0 or big[0, 1] < 0 or big[0, 2] > 640 or big[0, 3] > 360:
                continue
            ids = np.unique(inst[int(big[0, 1]):int(np.ceil(big[0, 3])),
                                 int(big[0, 0]):int(np.ceil(big[0, 2]))])
            if len(ids[ids != 0]) == 1:
                assert depicted_vehicles(rf, big)[0] == vid
                grown += 1
    assert checked >= 5 and grown >= 1
    # a box with no vehicle pixels (the sky row), and an empty box
    assert depicted_vehicles(rf, np.array([[0.0, 0.0, 40.0, 4.0], [5.0, 5.0, 5.0, 9.0]])
                             ).tolist() == [-1, -1]
    assert depicted_vehicles(rf, np.zeros((0, 4))).shape == (0,)
