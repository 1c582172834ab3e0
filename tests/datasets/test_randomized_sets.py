"""Randomized training sets: same labels as the plain set, other pixels, the drawn looks
recorded per image (detection) and per ring image (ReID), same seed → same bytes."""

from __future__ import annotations

import json
from dataclasses import replace

import pyarrow.parquet as pq
import pytest

from dashtraj.datasets.detection import DetectionConfig, build_detection_dataset
from dashtraj.datasets.frames import DatasetError
from dashtraj.datasets.reid import ReidConfig, build_reid_dataset, ring_look
from dashtraj.render.randomize import frame_rng, random_look, violations


def _files(root, pattern):
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.glob(pattern))
            if p.is_file()}


def test_randomized_detection_set(gl_available, recordings, tmp_path):
    plain = DetectionConfig(every_s=1.0, size=(160, 90))
    rand = DetectionConfig(every_s=1.0, size=(160, 90), randomize=True, randomize_seed=4)
    build_detection_dataset(recordings, tmp_path / "plain", plain)
    info = build_detection_dataset(recordings, tmp_path / "a", rand)
    build_detection_dataset(recordings, tmp_path / "b", rand, workers=2)
    a, b, p = tmp_path / "a", tmp_path / "b", tmp_path / "plain"
    fa, fb = _files(a, "**/*"), _files(b, "**/*")
    del fa["data.yaml"], fb["data.yaml"]  # holds the output's absolute path
    assert len(recordings) > 1 and fa == fb  # same seed, same bytes, with 1 or 2 processes
    assert _files(a, "labels/*/*.txt") == _files(p, "labels/*/*.txt")  # labels unchanged
    imgs_a, imgs_p = _files(a, "images/*/*.jpg"), _files(p, "images/*/*.jpg")
    assert imgs_a.keys() == imgs_p.keys()
    assert sum(imgs_a[k] != imgs_p[k] for k in imgs_a) == len(imgs_a)
    looks = pq.read_table(a / "looks.parquet").to_pylist()
    assert sorted(r["image"] for r in looks) == sorted(imgs_a)
    assert info["randomize"]["looks"] == "looks.parquet"
    assert json.loads((a / "dataset.json").read_text())["config"]["randomize"] is True
    for row in looks:  # each row is the look drawn for its frame, within the ranges
        stem = row["image"].rsplit("/", 1)[1][:-4]
        ri = int(stem[1:3])
        o, k = (int(x) for x in stem.rsplit("_o", 1)[1].split("_"))
        look = random_look(frame_rng(4, ri, o, k))
        assert look.flat() | {"image": row["image"]} == row
        assert violations(look) == []
    assert len({r["look_weather_sun_azimuth_angle"] for r in looks}) == len(looks)


def test_randomized_reid_set(gl_available, tmp_path):
    cfg = ReidConfig(n_ids=3, n_cameras=4, size=48, n_test_ids=1, seed=7, randomize=True,
                     randomize_seed=2, randomize_per="identity")
    info = build_reid_dataset(cfg, tmp_path / "r")
    root = tmp_path / "r"
    looks = pq.read_table(root / "looks.parquet").to_pylist()
    names = [ln for s in ("train", "query", "test")
             for ln in (root / f"name_{s}.txt").read_text().split()]
    assert sorted(r["image"].split("/")[1] for r in looks) == sorted(names)
    by_id: dict[int, set] = {}
    for r in looks:
        assert ring_look(cfg, r["id"] - 1, r["camera"]).flat() == {
            k: v for k, v in r.items() if k.startswith("look_")}
        by_id.setdefault(r["id"], set()).add(r["look_weather_sun_altitude_angle"])
        assert violations(ring_look(cfg, r["id"] - 1, r["camera"])) == []
    assert all(len(v) == 1 for v in by_id.values())  # one scene per identity
    assert len({next(iter(v)) for v in by_id.values()}) == len(by_id)
    assert info["randomize"]["seed"] == 2
    plain = build_reid_dataset(ReidConfig(n_ids=3, n_cameras=4, size=48, n_test_ids=1, seed=7),
                               tmp_path / "p")
    assert plain["counts"] == info["counts"] and "randomize" not in plain
    assert not (tmp_path / "p" / "looks.parquet").exists()
    ra, pa_ = _files(root, "image_*/*.jpg"), _files(tmp_path / "p", "image_*/*.jpg")
    assert ra.keys() == pa_.keys()  # the same crops are kept: visibility ignores the look
    assert all(ra[k] != pa_[k] for k in ra)


def test_reid_looks_per_image_and_test_only(gl_available, tmp_path):
    """The default draws a scene per ring image: no weather or light is tied to an identity
    (with one scene per identity, query and gallery of a test id share it, a shortcut);
    --test-only renders the same query and gallery and no training images."""
    cfg = ReidConfig(n_ids=3, n_cameras=4, size=48, n_test_ids=1, seed=7, randomize=True,
                     randomize_seed=2)
    assert cfg.randomize_per == "image"
    info = build_reid_dataset(cfg, tmp_path / "r")
    assert info["randomize"]["per"] == "image"
    looks = pq.read_table(tmp_path / "r" / "looks.parquet").to_pylist()
    by_id: dict[int, set] = {}
    for r in looks:
        by_id.setdefault(r["id"], set()).add(r["look_weather_sun_altitude_angle"])
    assert all(len(v) == sum(1 for r in looks if r["id"] == i) for i, v in by_id.items())
    assert max(len(v) for v in by_id.values()) > 1
    test = build_reid_dataset(replace(cfg, test_only=True), tmp_path / "t")
    assert test["counts"]["train"] == {"images": 0, "ids": 0}
    assert test["counts"]["query"] == info["counts"]["query"]
    assert test["counts"]["test"] == info["counts"]["test"]
    full = _files(tmp_path / "r", "image_query/*.jpg") | _files(tmp_path / "r", "image_test/*.jpg")
    only = _files(tmp_path / "t", "image_*/*.jpg")
    assert full == only  # the same bytes: an identity's images do not depend on the others
    with pytest.raises(DatasetError, match="--randomize-per 'scene'"):
        build_reid_dataset(replace(cfg, randomize_per="scene"), tmp_path / "bad")
