"""The YOLO detection set: label lines, data.yaml, split by recording."""

from __future__ import annotations

import json

import numpy as np

from dashtraj.datasets.detection import DetectionConfig, build_detection_dataset, split_units
from dashtraj.datasets.frames import recording_frames
from dashtraj.world.camera import DETECTION_CLASSES

SIZE = (160, 90)


def _read_labels(path):
    rows = []
    for line in path.read_text().splitlines():
        parts = line.split()
        assert len(parts) == 5, f"{path}: {line!r}"
        rows.append((int(parts[0]), *map(float, parts[1:])))
    return rows


def test_yolo_set(gl_available, recordings, tmp_path):
    cfg = DetectionConfig(every_s=1.0, size=SIZE, min_box_height_px=4, max_occlusion=0.7,
                          val_fraction=0.5, seed=3)
    info = build_detection_dataset(recordings, tmp_path, cfg)
    # data.yaml names the 15 classes in order
    text = (tmp_path / "data.yaml").read_text()
    assert "nc: 15" in text
    names = [ln.split(": ", 1)[1] for ln in text.splitlines() if ln.startswith("  ")]
    assert tuple(names) == DETECTION_CLASSES
    # split by recording: each recording's frames all on one side
    side = {}
    for split in ("train", "val"):
        for p in (tmp_path / "images" / split).glob("*.jpg"):
            side.setdefault(p.name.split("_o")[0], set()).add(split)
            assert (tmp_path / "labels" / split / (p.stem + ".txt")).is_file()
    assert len(side) == 2 and all(len(s) == 1 for s in side.values())
    assert {next(iter(s)) for s in side.values()} == {"train", "val"}
    assert info["split_by"] == "recording"
    # labels parse and match the frames' visible boxes after the filters
    rec = recordings[0]
    split = next(iter(side[f"r00_{rec.path.name}"]))
    n_boxes = 0
    for rf in recording_frames(rec, 1.0, SIZE):
        got = _read_labels(tmp_path / "labels" / split /
                           f"r00_{rec.path.name}_o{rf.observer_id}_{rf.frame:06d}.txt")
        want = []
        for lab in rf.frame_data.labels:
            b = lab.visible_box
            if b is None or b[3] - b[1] < 4 or lab.visible_fraction < 0.3:
                continue
            want.append((lab.detection_class_id, (b[0] + b[2]) / 2 / SIZE[0],
                         (b[1] + b[3]) / 2 / SIZE[1], (b[2] - b[0]) / SIZE[0],
                         (b[3] - b[1]) / SIZE[1]))
        assert len(got) == len(want)
        for g, w in zip(got, want, strict=True):
            assert g[0] == w[0] and 0 <= g[0] < 15
            assert np.allclose(g[1:], w[1:], atol=1e-6)
            assert all(0.0 <= v <= 1.0 for v in g[1:])
        n_boxes += len(got)
    assert n_boxes > 0
    meta = json.loads((tmp_path / "dataset.json").read_text())
    assert meta["config"]["size"] == list(SIZE)


def test_split_units():
    rng = np.random.default_rng(0)
    assert split_units(1, 0.2, rng).sum() == 0
    assert split_units(2, 0.2, rng).sum() == 1
    assert split_units(10, 0.2, rng).sum() == 2
    assert split_units(3, 0.99, rng).sum() == 2


def test_train_only_recordings_grow_train_and_keep_the_split(gl_available, recordings,
                                                            tmp_path):
    """A recording given as train-only lands in train whole; the other recordings' split
    and images are the bytes they are without it (it is appended after the split)."""
    cfg = DetectionConfig(every_s=1.0, size=SIZE, min_box_height_px=4, val_fraction=0.5,
                          seed=3)
    base = build_detection_dataset(recordings[:1], tmp_path / "a", cfg)
    grown = build_detection_dataset(recordings[:1], tmp_path / "b", cfg,
                                    train_only=recordings[1:])
    assert base["val"] == grown["val"] and base["split_by"] == grown["split_by"] == "observer"
    assert grown["train_only"] == [str(recordings[1].path)] and base["train_only"] == []
    for split in ("train", "val"):
        a = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob(f"{split}/*"))
        assert a and all((tmp_path / "b" / p).read_bytes() == (tmp_path / "a" / p).read_bytes()
                         for p in a)
    extra = [p for p in (tmp_path / "b" / "images").rglob("*.jpg")
             if p.name.startswith("r01_")]
    assert extra and all(p.parent.name == "train" for p in extra)
    assert grown["counts"]["val"] == base["counts"]["val"]
    assert grown["counts"]["train"]["images"] == \
        base["counts"]["train"]["images"] + len(extra)
