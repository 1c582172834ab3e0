"""`detector eval-external`: scoring the detector on another source's YOLO-labelled frames.

The frames are the real CARLA validation frames in ``../shared/carla_frames`` (never trained
on). Labels built from the detector's own mapped detections must score AP50 = 1 exactly,
which checks the class map, the NMS after the mapping, the box conversion and the metric
path end to end; the real labels give a real, finite figure.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from dashtraj.cli import main

CARLA = Path(__file__).resolve().parents[2] / ".." / "shared" / "carla_frames"
NAMES = "vehicle,bike,motobike,traffic_light,traffic_sign"
pytestmark = pytest.mark.skipif(not (CARLA / "images").is_dir(),
                                reason="../shared/carla_frames is not here")


@pytest.fixture(scope="module")
def few_frames(tmp_path_factory) -> Path:
    """Four CARLA frames with vehicles, with their own labels."""
    root = tmp_path_factory.mktemp("carla8")
    (root / "images").mkdir()
    (root / "labels").mkdir()
    picked = 0
    for lab in sorted((CARLA / "labels").glob("*.txt")):
        rows = [ln.split() for ln in lab.read_text().splitlines() if ln.strip()]
        if sum(r[0] == "0" for r in rows) >= 2:
            shutil.copy(CARLA / "images" / (lab.stem + ".jpg"), root / "images")
            shutil.copy(lab, root / "labels")
            picked += 1
        if picked == 4:
            break
    (root / "classes.txt").write_text(NAMES.replace(",", "\n") + "\n")
    return root


def test_own_detections_as_labels_score_ap50_one(few_frames, tmp_path):
    from PIL import Image

    from dashtraj.perception.detect import YoloDetector, nms
    from dashtraj.perception.detector_eval import DEFAULT_CLASS_MAP, evaluate_external

    det = YoloDetector(conf=0.001, iou=0.6)
    theirs = NAMES.split(",")
    set_dir = tmp_path / "own"
    shutil.copytree(few_frames / "images", set_dir / "images")
    (set_dir / "labels").mkdir()
    n_boxes = 0
    for img in sorted((set_dir / "images").glob("*.jpg")):
        rgb = np.asarray(Image.open(img).convert("RGB"))
        h, w = rgb.shape[:2]
        d = det.detect([rgb])[0]
        cls = np.array([theirs.index(DEFAULT_CLASS_MAP[n.rsplit("_", 1)[0]])
                        for n in d.labels], np.int64)
        k = nms(d.boxes, d.scores, 0.6, classes=cls)
        k = k[d.scores[k] >= 0.3]
        lines = []
        for (x0, y0, x1, y1), c in zip(d.boxes[k], cls[k], strict=True):
            lines.append(f"{c} {(x0 + x1) / 2 / w:.9f} {(y0 + y1) / 2 / h:.9f} "
                         f"{(x1 - x0) / w:.9f} {(y1 - y0) / h:.9f}")
        n_boxes += len(lines)
        (set_dir / "labels" / (img.stem + ".txt")).write_text("\n".join(lines) + "\n")
    assert n_boxes >= 2
    res = evaluate_external(set_dir, det, theirs)
    assert res["images"] == 4
    for name, v in res["per_class"].items():
        assert v["ap50"] == pytest.approx(1.0), name
    # class-agnostic: the NMS over all classes may merge a bike's box into an overlapping
    # vehicle's, so one label in a few can go unmatched
    assert res["any_ap50"] >= 0.9
    assert res["recall"] == pytest.approx(1.0)


def test_cli_on_real_labels_writes_json(few_frames, tmp_path, capsys):
    out = tmp_path / "ev"
    assert main(["detector", "eval-external", str(few_frames), "-q", "--json",
                 "-o", str(out)]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["names"] == NAMES.split(",")
    assert res["scored_classes"] == ["vehicle", "bike", "motobike"]
    assert res["vehicle_class"] == "vehicle"
    assert res["per_class"]["vehicle"]["gt"] >= 8
    assert 0.0 <= res["vehicle_ap50"] <= 1.0
    assert json.loads((out / "eval.json").read_text())["images"] == 4


def test_set_with_vehicle_only_uses_the_restricted_default_map(few_frames, tmp_path, capsys):
    one = tmp_path / "one"
    shutil.copytree(few_frames / "images", one / "images")
    (one / "labels").mkdir()
    for lab in (few_frames / "labels").glob("*.txt"):
        keep = [ln for ln in lab.read_text().splitlines() if ln.startswith("0 ")]
        (one / "labels" / lab.name).write_text("\n".join(keep) + "\n")
    assert main(["detector", "eval-external", str(one), "--names", "vehicle", "-q",
                 "--json", "--max-images", "1"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["class_map"] == {"car": "vehicle", "truck": "vehicle", "bus": "vehicle"}
    assert res["scored_classes"] == ["vehicle"]


@pytest.mark.parametrize("line,frag", [("7 0.5 0.5 0.1 0.1", "class id 0..4"),
                                       ("0 0.5 0.5 0.1", "expected 'class cx cy w h'"),
                                       ("0 0.5 nan 0.1 0.1", "expected 'class cx cy w h'")])
def test_bad_label_line_names_file_and_line(few_frames, tmp_path, capsys, line, frag):
    bad = tmp_path / "bad"
    shutil.copytree(few_frames, bad)
    lab = sorted((bad / "labels").glob("*.txt"))[2]
    lab.write_text(lab.read_text() + line + "\n")
    n = len(lab.read_text().splitlines())
    assert main(["detector", "eval-external", str(bad), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{lab}:{n}:" in err[0] and frag in err[0]
