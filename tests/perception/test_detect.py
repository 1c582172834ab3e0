"""Run time of the detector: letterbox and NMS round trips, output decoding, class names.
(The ONNX session itself is tested with the shipped model in test_detector_shipped.py.)"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dashtraj.perception.detect import (
    PAD_VALUE,
    DetectorError,
    box_iou,
    letterbox,
    letterbox_geometry,
    names_from_metadata,
    nms,
    postprocess,
    read_names_yaml,
)


@settings(max_examples=60, deadline=None)
@given(st.integers(16, 3000), st.integers(16, 3000),
       st.sampled_from([(384, 640), (640, 640), (288, 512), (320, 320)]))
def test_letterbox_boxes_round_trip_exactly(w0, h0, input_hw):
    lb = letterbox_geometry((h0, w0), input_hw)
    rng = np.random.default_rng(w0 * 7 + h0)
    xy = rng.uniform(0, [w0, h0], (20, 2))
    wh = rng.uniform(0, 1, (20, 2)) * (np.array([w0, h0]) - xy)
    boxes = np.concatenate([xy, xy + wh], 1)
    back = lb.boxes_to_image(np.concatenate([lb.boxes_to_input(boxes), np.ones((20, 2))], 1))
    np.testing.assert_allclose(back[:, :4], boxes, rtol=0, atol=1e-9 * max(w0, h0))
    # the frame fits in the input and is centred: the padding differs by at most a pixel
    nw, nh = round(w0 * lb.scale), round(h0 * lb.scale)
    assert nw <= input_hw[1] and nh <= input_hw[0]
    assert (nw == input_hw[1]) or (nh == input_hw[0])
    assert abs((input_hw[1] - nw - lb.pad_x) - lb.pad_x) <= 1
    assert abs((input_hw[0] - nh - lb.pad_y) - lb.pad_y) <= 1


def test_letterbox_image_places_the_frame():
    rgb = np.zeros((720, 1280, 3), np.uint8)
    rgb[100:300, 200:600] = (255, 0, 0)
    img, lb = letterbox(rgb, (384, 640))
    assert img.shape == (384, 640, 3) and lb.scale == 0.5 and (lb.pad_x, lb.pad_y) == (0, 12)
    assert (img[:12] == PAD_VALUE).all() and (img[-12:] == PAD_VALUE).all()
    # the red block maps to rows 12+50..12+150, columns 100..300
    assert (img[12 + 52:12 + 148, 102:298, 0] == 255).all()
    assert (img[12 + 52:12 + 148, 102:298, 1] == 0).all()
    np.testing.assert_allclose(lb.boxes_to_input([[200, 100, 600, 300]]),
                               [[100, 62, 300, 162]])
    # a frame of the input's size is copied unchanged
    same, lb1 = letterbox(img, (384, 640))
    assert lb1.scale == 1 and (same == img).all()


def _nms_reference(boxes, scores, thr, classes):
    """Brute force: walk boxes in score order, keep one unless a kept box of its class
    overlaps it by more than thr."""
    kept = []
    for i in sorted(range(len(scores)), key=lambda i: (-scores[i], i)):
        if all(classes[j] != classes[i] or box_iou(boxes[i], boxes[j])[0, 0] <= thr
               for j in kept):
            kept.append(i)
    return kept


@pytest.mark.parametrize("seed", range(5))
def test_nms_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    n = 60
    xy = rng.uniform(0, 200, (n, 2))
    boxes = np.concatenate([xy, xy + rng.uniform(10, 60, (n, 2))], 1)
    scores = rng.uniform(0, 1, n)
    classes = rng.integers(0, 3, n)
    keep = nms(boxes, scores, 0.5, classes)
    assert keep.tolist() == _nms_reference(boxes, scores, 0.5, classes)
    # max_keep stops early with the first boxes of the full answer
    for k in (1, 5, len(keep), len(keep) + 3):
        assert nms(boxes, scores, 0.5, classes, max_keep=k).tolist() == keep[:k].tolist()
    # class-agnostic: a subset of the class-aware result, pairwise below the threshold
    agn = nms(boxes, scores, 0.5)
    ov = box_iou(boxes[agn], boxes[agn])
    assert (ov[~np.eye(len(agn), dtype=bool)] <= 0.5).all()
    assert set(agn.tolist()) <= set(keep.tolist())


def test_nms_keeps_overlapping_boxes_of_different_classes():
    boxes = np.array([[0, 0, 10, 10], [0, 0, 10, 10.5], [0, 0, 10, 10]], float)
    scores = np.array([0.9, 0.8, 0.7])
    assert nms(boxes, scores, 0.5, np.array([0, 0, 1])).tolist() == [0, 2]


def test_postprocess_decodes_the_ultralytics_layout():
    nc, n = 3, 6
    raw = np.zeros((1, 4 + nc, n), np.float32)
    # cell 1: class 2 at 0.9, box centre (50, 40), 20 x 10; cell 4: a duplicate at 0.6
    raw[0, :4, 1] = [50, 40, 20, 10]
    raw[0, 4 + 2, 1] = 0.9
    raw[0, :4, 4] = [51, 40, 20, 10]
    raw[0, 4 + 2, 4] = 0.6
    raw[0, :4, 3] = [10, 10, 4, 4]  # below the threshold
    raw[0, 4 + 0, 3] = 0.1
    out = postprocess(raw, conf=0.25, iou=0.5)
    assert len(out) == 1
    np.testing.assert_allclose(out[0], [[40, 35, 60, 45, 0.9, 2]], atol=1e-6)
    with pytest.raises(DetectorError, match="expected"):
        postprocess(np.zeros((1, 3, 5)))


def test_names_from_data_yaml_and_metadata(tmp_path):
    y = tmp_path / "data.yaml"
    y.write_text("path: x\nnames:\n  0: car\n  1: 'bus'\nnc: 2\n")
    assert read_names_yaml(y) == ["car", "bus"]
    y.write_text("names: [car, bus, bike]\n")
    assert read_names_yaml(y) == ["car", "bus", "bike"]
    y.write_text("names:\n- car\n- truck\n")
    assert read_names_yaml(y) == ["car", "truck"]
    y.write_text("nc: 2\n")
    with pytest.raises(DetectorError, match="no 'names:'"):
        read_names_yaml(y)
    assert names_from_metadata({"names": "{0: 'car', 1: 'bus'}"}) == ["car", "bus"]
    assert names_from_metadata({}) is None
