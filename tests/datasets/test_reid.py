"""The VeRi-layout ReID set: names, splits, determinism across worker counts."""

from __future__ import annotations

import json
import re

from dashtraj.datasets.reid import (
    NAME_PATTERN,
    ReidConfig,
    build_reid_dataset,
    moving_queries,
    ring_cameras,
)

CFG = ReidConfig(n_ids=6, n_cameras=5, size=64, n_test_ids=2, seed=7)


def _tree(root):
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file()}


def test_reid_set(gl_available, tmp_path):
    info = build_reid_dataset(CFG, tmp_path / "w1", workers=1)
    build_reid_dataset(CFG, tmp_path / "w2", workers=2)
    a, b = _tree(tmp_path / "w1"), _tree(tmp_path / "w2")
    assert a == b  # byte-identical with 1 and 2 workers
    root = tmp_path / "w1"
    ids = {}
    for split in ("train", "query", "test"):
        files = sorted(p.name for p in (root / f"image_{split}").iterdir())
        listed = (root / f"name_{split}.txt").read_text().split()
        assert files == listed
        assert all(re.match(NAME_PATTERN, n) for n in files)
        ids[split] = {int(n[:4]) for n in files}
    assert ids["train"] == {1, 2, 3, 4}
    assert ids["query"] == ids["test"] == {5, 6}
    for vid in (5, 6):  # query and gallery of a test id come from distinct cameras
        q = {n[6:9] for n in (root / "name_query.txt").read_text().split() if int(n[:4]) == vid}
        g = {n[6:9] for n in (root / "name_test.txt").read_text().split() if int(n[:4]) == vid}
        assert q and g and not q & g and len(q | g) == 5
    assert info["ids"][0] == {"id": 1, "identity_id": 0, "key": info["ids"][0]["key"],
                              "class": info["ids"][0]["class"], "split": "train"}
    assert json.loads((root / "reid.json").read_text())["counts"]["train"]["images"] == 20


def test_ring_cameras_are_seeded():
    cams = ring_cameras(ReidConfig(n_cameras=85, seed=1))
    assert cams == ring_cameras(ReidConfig(n_cameras=85, seed=1))
    assert cams != ring_cameras(ReidConfig(n_cameras=85, seed=2))
    assert [c.index for c in cams] == list(range(1, 86))
    assert all(4.0 - 1e-9 <= c.distance_m <= 15.0 and 1.2 <= c.height_m <= 3.5 for c in cams)


def test_moving_queries(gl_available, recordings, tmp_path):
    rec = recordings[0]
    top = max(int(v["identity_id"]) for v in rec.vehicles) + 1
    cfg = ReidConfig(n_ids=top, n_test_ids=top, n_cameras=85, size=32, every_s=1.0,
                     min_box_height_px=8)
    out = moving_queries([rec], tmp_path, cfg)
    files = sorted(p.name for p in (tmp_path / "image_query_moving").iterdir())
    assert files == (tmp_path / "name_query_moving.txt").read_text().split()
    assert out["counts"]["images"] == len(files) > 0
    assert all(re.match(NAME_PATTERN, n) and int(n[6:9]) > 85 for n in files)
