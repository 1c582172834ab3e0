"""`dashtraj perceive` on a drive (images and camera poses on disk, no renderer): a recording
rendered to a lossless drive perceives to its own database, truth aside; bad drives are
one-line errors naming the file, line or field."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from PIL import Image

from dashtraj.cli import main
from dashtraj.datasets.drive import Drive, DriveError, DrivePose, write_drive
from dashtraj.store import SightingsDB
from dashtraj.world.camera import CameraSpec
from dashtraj.world.towns import town_path


@pytest.fixture(scope="module")
def rendered_drive(small_run, gl_available, tmp_path_factory):
    """`small_run` rendered as a lossless drive every 0.5 s, with depth images."""
    out = tmp_path_factory.mktemp("drive") / "drive"
    assert main(["render", str(small_run.path), "-o", str(out), "--every", "0.5", "--png",
                 "--depth", "-q"]) == 0
    return out


def test_a_rendered_drive_perceives_as_its_recording(small_run, rendered_drive, tmp_path,
                                                     capsys):
    """`render --png` writes a drive; perceiving its images gives the rows that rendering
    the same frames on the fly gives (boxes, scores, tracks, positions, crops). Its
    truth.csv and depth images give the truth columns the renderer gives; truth.csv alone
    (boxes from the 3-D boxes' outlines) the same vehicle for nearly every detection and
    never another one; without truth.csv they are empty."""
    import shutil

    from dashtraj.perception.detect import default_model_path
    from dashtraj.perception.pipeline import PerceiveConfig, perceive

    drive_dir = tmp_path / "drive"
    shutil.copytree(rendered_drive, drive_dir)
    drive = Drive.open(drive_dir)
    assert drive.observer_ids == [1, 2, 3] and len(drive.frame_poses(1)) == 51
    assert drive.config.camera == small_run.config.camera and drive.truth is not None
    model = str(default_model_path())
    ref = tmp_path / "ref.db"
    perceive(small_run, ref, PerceiveConfig(detector=model, every_s=0.5, msaa=4,
                                            observers=(1, 3)))

    def run(name):
        out = tmp_path / name
        assert main(["perceive", str(drive_dir), "-o", str(out), "--detector", model,
                     "--every", "0.5", "--observers", "1", "3", "-q", "--json"]) == 0
        assert json.loads(capsys.readouterr().out.splitlines()[-1])["frames"] == 102
        return out

    with_depth = run("depth.db")
    for p in drive_dir.glob("*/*.depth.png"):
        p.unlink()
    hull = run("hull.db")
    (drive_dir / "truth.csv").unlink()
    bare = run("bare.db")

    def no_truth(rows):
        return [dataclasses.replace(r, truth_vehicle_id=None, **(
            {"depicted_vehicle_id": None} if hasattr(r, "depicted_vehicle_id") else {}))
            for r in rows]

    with SightingsDB.open(ref) as a, SightingsDB.open(with_depth) as b, \
            SightingsDB.open(hull) as c, SightingsDB.open(bare) as d:
        assert a.poses() == b.poses() == d.poses()
        dets = a.detections()
        assert len(dets) > 50 and any(r.truth_vehicle_id is not None for r in dets)
        for db in (b, c):
            assert no_truth(dets) == no_truth(db.detections()) == d.detections()
            assert no_truth(a.tracks()) == no_truth(db.tracks()) == d.tracks()
        assert a.crops() == d.crops() and len(a.crops()) > 0
        assert d.run_info()["map_sha256"] == a.run_info()["map_sha256"]
        for db, share in ((b, 0.99), (c, 0.95)):  # with depth; from the boxes alone
            got = db.detections()
            for col in ("truth_vehicle_id", "depicted_vehicle_id"):
                pairs = [(getattr(x, col), getattr(y, col))
                         for x, y in zip(dets, got, strict=True)]
                same = sum(p == q for p, q in pairs)
                assert same >= share * len(pairs), (col, same, len(pairs))
                assert not [p for p in pairs if None not in p and p[0] != p[1]], col
        assert [t.truth_vehicle_id for t in a.tracks()] == \
            [t.truth_vehicle_id for t in b.tracks()]


def test_a_rendered_drive_with_depth_scores_as_its_recording(small_run, rendered_drive,
                                                             capsys):
    """`tracker eval`, `localization eval` and `detector eval` read a drive's truth: with
    depth images its truth boxes are the renderer's to a pixel or two, so the scores are
    the recording's."""
    def scores(cmd, path, *extra, every="0.5"):
        assert main([*cmd, str(path), "--every", every, "--json", *extra]) == 0
        return json.loads(capsys.readouterr().out)

    a = scores(["tracker", "eval"], small_run.path, "--peers")
    b = scores(["tracker", "eval"], rendered_drive, "--peers")
    assert a["frames"] == b["frames"] == 153
    for n in ("ego", "sort"):
        for k in ("idf1", "hota", "mota"):
            assert b[n][k] == pytest.approx(a[n][k], abs=0.02), (n, k)
    a = scores(["localization", "eval"], small_run.path, "--track-every", "0.5")
    b = scores(["localization", "eval"], rendered_drive, "--track-every", "0.5")
    for n in ("ground", "mapped"):
        assert b[n]["n_lt20"] == a[n]["n_lt20"] > 20
        assert b[n]["rmse_lt20_m"] == pytest.approx(a[n]["rmse_lt20_m"], abs=0.25), n
    a = scores(["detector", "eval"], small_run.path, "-q", every="2")
    b = scores(["detector", "eval"], rendered_drive, "-q", every="2")
    assert a["frames"] == b["frames"] == 39 and a["class_counts"] == b["class_counts"]
    for k in ("map50", "map50_95"):
        assert b[k] == pytest.approx(a[k], abs=0.03), k


def _tiny_drive(root, frames=((0, 0.0), (1, 0.05), (2, 0.1)), size=(32, 24)):
    """A drive of one observer on town01 with grey images."""
    cam = CameraSpec(width_px=size[0], height_px=size[1])
    poses = [DrivePose(7, f, t, 100.0 + t, 5.0, 1.6, 90.0, 0.0) for f, t in frames]
    write_drive(root, town_path("town01"), cam, poses)
    (root / "7").mkdir()
    for f, _ in frames:
        Image.new("RGB", size, (90, 90, 90)).save(root / "7" / f"{f:06d}.png")
    return root


def test_frames_are_sampled_one_per_period_whatever_the_timestamps(tmp_path):
    ts = [0.0, 0.05, 0.1, 0.15, 0.2, 0.3, 0.31, 0.52]
    d = Drive.open(_tiny_drive(tmp_path / "d", frames=list(enumerate(ts))))
    assert [p.t for p in d.frame_poses(7)] == ts
    assert [p.t for p in d.frame_poses(7, 0.1)] == [0.0, 0.1, 0.2, 0.3, 0.52]
    assert [p.t for p in d.frame_poses(7, 0.25)] == [0.0, 0.3, 0.52]
    (f,) = list(d.frames(7, 1.0))
    assert f.frame_data.rgb.shape == (24, 32, 3) and f.frame_data.camera_pose[:3] == (
        100.0, 5.0, 1.6)


def _edit(path, fn):
    path.write_text(fn(path.read_text()))


@pytest.mark.parametrize("damage, message", [
    (lambda r: (r / "drive.json").write_text("{not json"), "drive.json: not JSON"),
    (lambda r: _edit(r / "drive.json", lambda s: s.replace("dashtraj-drive", "x")),
     "not a dashtraj drive"),
    (lambda r: _edit(r / "drive.json", lambda s: s.replace('"format_version": 1',
                                                          '"format_version": 9')),
     "format_version 9 is newer"),
    (lambda r: _edit(r / "drive.json", lambda s: s.replace('"fov_deg": 90.0',
                                                          '"fov_deg": 190.0')),
     "camera fov_deg must be a number in [1, 179]"),
    (lambda r: _edit(r / "drive.json", lambda s: s.replace('"fov_deg"', '"fov"')),
     "camera must be an object with fields among"),
    (lambda r: _edit(r / "drive.json", lambda s: s.replace('"map.xodr"', '"nowhere.xodr"')),
     "map 'nowhere.xodr'"),
    (lambda r: _edit(r / "poses.csv", lambda s: s.replace("cam_yaw", "heading")),
     "poses.csv: missing column 'cam_yaw'"),
    (lambda r: _edit(r / "poses.csv", lambda s: s.replace("100.05", "abc")),
     "poses.csv, line 3: observer_id and frame must be integers"),
    (lambda r: _edit(r / "poses.csv", lambda s: s + s.splitlines()[1] + "\n"),
     "observer 7 frame 0 appears twice"),
    (lambda r: (r / "7" / "000001.png").unlink(), "observer 7 frame 1 has no image"),
    (lambda r: Image.new("RGB", (64, 24)).save(r / "7" / "000002.png"),
     "000002.png: 64x24 pixels, the camera in drive.json is 32x24"),
    (lambda r: (r / "7" / "000002.png").write_bytes(b"not a picture"),
     "000002.png: not an image"),
])
def test_bad_drives_are_one_line_errors(tmp_path, capsys, damage, message):
    root = _tiny_drive(tmp_path / "d")
    damage(root)
    with pytest.raises(DriveError) as exc:
        Drive.open(root)
    assert message in str(exc.value)
    out = tmp_path / "x.db"
    assert main(["perceive", str(root), "-o", str(out), "--detector", "m.onnx", "-q"]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not out.exists()


@pytest.mark.parametrize("args, message", [
    ([], "has no truth.csv for --detector oracle"),
    (["--detector", "{MODEL}", "--size", "64x48"], "--size applies to rendered recordings"),
    (["--detector", "{MODEL}", "--msaa", "4"], "--msaa applies to rendered recordings"),
])
def test_options_that_need_a_renderer_are_refused_on_a_drive(tmp_path, capsys, args,
                                                             message):
    from dashtraj.perception.detect import default_model_path

    root = _tiny_drive(tmp_path / "d")
    args = [a.replace("{MODEL}", str(default_model_path())) for a in args]
    out = tmp_path / "x.db"
    assert main(["perceive", str(root), "-o", str(out), "-q", *args]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not out.exists()


def test_a_drive_of_grey_images_perceives_to_an_empty_but_whole_database(tmp_path):
    from dashtraj.perception.detect import default_model_path

    root = _tiny_drive(tmp_path / "d", size=(64, 48))
    out = tmp_path / "x.db"
    assert main(["perceive", str(root), "-o", str(out), "--detector",
                 str(default_model_path()), "-q"]) == 0
    with SightingsDB.open(out) as db:
        assert db.observers() == [{"observer_id": 7, "role": None, "frames": 2,
                                   "complete": True}]
        assert db.count("detections") == 0 and db.run_info()["complete"]
        assert np.allclose([p.cam_x for p in db.poses()], [100.0, 100.1])


def test_commands_that_need_a_recording_say_a_drive_is_not_one(tmp_path, capsys):
    root = _tiny_drive(tmp_path / "d")
    assert main(["render", str(root), "-o", str(tmp_path / "x"), "-q"]) == 2
    err = capsys.readouterr().err
    assert "is a drive (images and camera poses), not a simulated recording" in err
    assert err.count("\n") == 1 and not (tmp_path / "x").exists()
    for cmd in (["tracker", "eval"], ["localization", "eval"], ["detector", "eval"]):
        # these read a drive's truth
        assert main([*cmd, str(root), "--json"]) == 2
        err = capsys.readouterr().err
        assert "is a drive without truth.csv: nothing to score against" in err
        assert err.count("\n") == 1
    out = tmp_path / "set"
    assert main(["detection-dataset", str(root), "-o", str(out), "-q"]) == 2
    err = capsys.readouterr().err
    assert "is a drive without truth.csv: no labels for a detection set" in err
    assert err.count("\n") == 1 and not out.exists()
    assert main(["reid", "drive-set", str(root), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "is a drive without truth.csv" in err and err.count("\n") == 1
    assert not out.exists()


def test_a_drive_is_an_experiment_from_its_own_images(rendered_drive, tmp_path, capsys):
    """`experiments --drives`: the paper's experiment on a recorded drive (what
    carla-record writes): perceive its images, find its truth's target by appearance,
    score the route against its target_route.csv."""
    out = tmp_path / "exp"
    assert main(["experiments", "--drives", str(rendered_drive), "--detector", "oracle",
                 "-o", str(out), "--json", "-q"]) == 0
    res = json.loads(capsys.readouterr().out)
    (e,) = res["experiments"]
    run = out / rendered_drive.name
    for name in ("sightings.db", "sightings.csv", "truth.csv", "estimate_hmm.csv",
                 "estimate_shortest-path.csv", "summary.json"):
        assert (run / name).is_file(), name
    assert not (run / "recording").exists()
    s = json.loads((run / "summary.json").read_text())
    assert s["config"]["drive"] == str(rendered_drive) and s["config"]["image_size"] is None
    assert s["reid_true_matches"] >= 1 and s["reid_precision"] == 1.0
    assert e["experiment"] == rendered_drive.name
    assert s["methods"]["hmm"]["sspd_seen_m"] == e["methods"]["hmm"]["sspd_seen_m"] < 5.0
    # the route it is scored against is the recording's
    assert (run / "truth.csv").read_text() == (rendered_drive / "target_route.csv").read_text()


@pytest.mark.parametrize("args, message", [
    (["--seeds", "0-2"], "--seeds does not apply to --drives"),
    (["--size", "64x48"], "--size does not apply to --drives"),
    (["--ablation"], "--drives with --ablation"),
    (["--sightings", "oracle"], "--drives runs from pixels"),
])
def test_experiments_on_drives_refuse_what_needs_a_simulation(tmp_path, capsys, args,
                                                             message):
    root = _tiny_drive(tmp_path / "d")
    out = tmp_path / "exp"
    assert main(["experiments", "--drives", str(root), "-o", str(out), *args]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and not out.exists()


def test_an_experiment_needs_a_drive_with_truth_and_a_route(tmp_path, capsys):
    from dashtraj.datasets.drive_truth import write_truth

    root = _tiny_drive(tmp_path / "d")
    out = tmp_path / "exp"
    assert main(["experiments", "--drives", str(root), "-o", str(out)]) == 2
    assert "no truth.csv" in capsys.readouterr().err
    write_truth(root / "truth.csv", [(0.0, 1, "target", "x", "car", 1, 1, 0, 0, 2, 1, 1)])
    assert main(["experiments", "--drives", str(root), "-o", str(out)]) == 2
    assert "no target_route.csv" in capsys.readouterr().err and not out.exists()


def test_a_drive_with_truth_is_a_detection_set_like_its_recording(small_run, rendered_drive,
                                                                  tmp_path):
    """`detection-dataset DRIVE`: a drive's own images (CARLA's, from carla-record) with
    labels from its truth; rendered from a recording, the same images and labels to a
    pixel."""
    sets = {}
    for name, src in (("rec", small_run.path), ("drive", rendered_drive)):
        out = tmp_path / name
        assert main(["detection-dataset", str(src), "-o", str(out), "--size", "320x180",
                     "--every", "0.5", "-q"]) == 0
        imgs = sorted(out.glob("images/*/*.jpg"))
        sets[name] = ([p.read_bytes() for p in imgs],
                      [[ln.split() for ln in p.with_suffix(".txt").read_text().splitlines()]
                       for p in (out / "labels" / q.parent.name / q.name for q in imgs)])
    (img_a, lab_a), (img_b, lab_b) = sets["rec"], sets["drive"]
    assert len(img_a) == 153 and img_a == img_b
    n = 0
    for a, b in zip(lab_a, lab_b, strict=True):  # the same boxes, perhaps in another order
        assert sorted(r[0] for r in a) == sorted(r[0] for r in b)
        for ra in a:
            n += 1
            px = min((np.abs(np.array(ra[1:], float) - np.array(rb[1:], float))
                      * [320, 180, 320, 180]).max() for rb in b if rb[0] == ra[0])
            assert px <= 1.5, (ra, b)
    assert n > 30


def test_a_drive_with_truth_is_a_reid_set_in_the_veri_layout(rendered_drive, tmp_path,
                                                             capsys):
    """`reid drive-set`: every vehicle an identity, every observer a camera; train and test
    identities apart; queries from cameras that are not their gallery's; `reid eval`
    reads it."""
    import re

    from dashtraj.datasets.reid import NAME_PATTERN

    out = tmp_path / "set"
    assert main(["reid", "drive-set", str(rendered_drive), "-o", str(out), "--min-box-height",
                 "16", "--json"]) == 0
    counts = json.loads(capsys.readouterr().out)
    info = json.loads((out / "reid.json").read_text())
    assert [c["observer_id"] for c in info["cameras"]] == [1, 2, 3]
    ids = {s: set() for s in ("train", "query", "test")}
    cams = {s: {} for s in ("query", "test")}
    for s in ids:
        names = (out / f"name_{s}.txt").read_text().split()
        assert sorted(p.name for p in (out / f"image_{s}").iterdir()) == names
        assert len(names) == counts[s]["images"]
        for n in names:
            assert re.match(NAME_PATTERN, n), n
            ids[s].add(int(n[:4]))
            if s in cams:
                cams[s].setdefault(int(n[:4]), set()).add(int(n[6:9]))
    assert ids["train"] and ids["query"] and not ids["train"] & (ids["query"] | ids["test"])
    assert ids["query"] <= ids["test"]
    for vid, qc in cams["query"].items():  # a query's camera holds none of its gallery
        assert not qc & cams["test"][vid]
    by_id = {i["id"]: i for i in info["identities"]}
    assert {by_id[i]["split"] for i in ids["train"]} == {"train"}
    assert main(["reid", "eval", "--data", str(out), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["queries"] == counts["query"]["images"] and 0.0 <= res["rank1"] <= 1.0
    # one drive twice would make each of its vehicles two identities
    again = tmp_path / "again"
    assert main(["reid", "drive-set", str(rendered_drive), str(rendered_drive), "-o",
                 str(again)]) == 2
    err = capsys.readouterr().err
    assert "is given twice" in err and err.count("\n") == 1 and not again.exists()
