"""The calibrated threshold file beside a ReID model, and the stage switches."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dashtraj.reid.embed import shipped_model_path
from dashtraj.reidentify.vision import (
    StageSwitches,
    VisionReidError,
    expansion_crops,
    load_threshold,
    sha256_of,
    threshold_path,
)


def test_shipped_model_has_a_threshold_calibrated_on_training_recordings():
    th = load_threshold(shipped_model_path())
    assert th.model_sha256 == sha256_of(shipped_model_path())
    c = th.calibration
    assert 0.0 < c.threshold < 2.0 and c.positives > 0 and c.negatives > 0
    srcs = th.provenance["sources"]
    # training seeds and the ReID set's training identities only, never the test seeds 0-4
    assert srcs and all(s["seed"] not in range(5) for s in srcs)
    assert all(s["identity_range"] == [0, 650] for s in srcs)
    assert "reid-threshold" in th.provenance["recompute"]


def test_stale_or_missing_threshold_is_refused(tmp_path):
    model = tmp_path / "m.onnx"
    model.write_bytes(b"not the calibrated model")
    with pytest.raises(VisionReidError, match=r"no calibrated ReID threshold for m\.onnx"):
        load_threshold(model)
    d = json.loads(threshold_path(shipped_model_path()).read_text())
    threshold_path(model).write_text(json.dumps(d))
    with pytest.raises(VisionReidError, match=r"replaced\?\); recompute: make reid-threshold"):
        load_threshold(model)
    d["model_sha256"] = sha256_of(model)
    threshold_path(model).write_text(json.dumps(d))
    assert load_threshold(model).calibration.threshold == d["calibration"]["threshold"]
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(VisionReidError, match="not a threshold file"):
        load_threshold(model, tmp_path / "bad.json")


def test_switch_names_are_checked():
    with pytest.raises(VisionReidError,
                       match="unknown tracks switch 'sort'; valid: tracker, truth"):
        StageSwitches(tracks="sort")


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def test_query_expansion_keeps_only_the_crops_the_query_crop_accepts():
    # a query track that the tracker carried from the scenery onto the target: the
    # scenery's crops are far from the query crop and must not enter the mean
    q = _unit([1.0, 0.0, 0.0])
    emb = np.stack([
        q,                           # 0: the query crop itself (distance 0)
        _unit([0.95, 0.31, 0.0]),    # 1: the target, another view: 1 - 0.95 = 0.05
        _unit([0.0, 1.0, 0.0]),      # 2: scenery before the switch: distance 1.0
        _unit([0.7, 0.0, 0.714]),    # 3: distance 0.30, just above a 0.256 threshold
    ])
    assert expansion_crops(q, emb, [0, 1, 2, 3], 0.256) == [0, 1]
    assert expansion_crops(q, emb, [2, 3, 1], 0.31) == [3, 1]
    assert expansion_crops(q, emb, [], 0.256) == []
    # a pure track keeps every crop within the threshold: the mean is the old one
    assert expansion_crops(q, emb, [0, 1], 0.256) == [0, 1]
