"""From pixels: `--sightings vision` end to end, one reconstruction path for every source,
and the error budget's rows."""

from __future__ import annotations

import json

import numpy as np
import pytest

import dashtraj.experiments as ex
from dashtraj.cli import main
from dashtraj.reid.embed import shipped_model_path
from dashtraj.reidentify.vision import load_threshold

# A small town01 scene (3 observers, 10 agents, 30 s, 256 x 144 frames) where the target
# passes near other vehicles: 4 tracks are in the 15 m ReID range.
SMALL = dict(town="town01", seed=0, observers=3, agents=10, duration_s=30.0,
             image_size=(256, 144), detector="oracle")


@pytest.fixture
def spy(monkeypatch):
    """Record every call of `dashtraj.experiments.reconstruct_and_score`."""
    calls: list[dict] = []
    real = ex.reconstruct_and_score

    def wrapped(road_map, truth, sightings, methods, out=None, pose_noise=None):
        res = real(road_map, truth, sightings, methods, out, pose_noise)
        calls.append({"sightings": list(sightings), "results": res[0]})
        return res

    monkeypatch.setattr(ex, "reconstruct_and_score", wrapped)
    return calls


@pytest.mark.slow
def test_demo_from_pixels_finds_the_target_and_writes_every_file(tmp_path, gl_available,
                                                                  capsys, spy):
    # `dashtraj demo`'s defaults: from pixels, the shipped detector and ReID model and the
    # threshold beside it, 640 x 360 frames every 0.2 s, two perception workers
    out = tmp_path / "demo"
    assert main(["demo", "--town", "town01", "--seed", "0", "--observers", "3", "--agents",
                 "10", "--duration", "30", "-o", str(out)]) == 0
    captured = capsys.readouterr()
    printed, progress = captured.out, captured.err
    assert "from pixels, detector shipped" in printed and "ReID:" in printed
    assert "time: simulate" in printed
    # a progress line for every stage
    for stage in ("simulate:", "perceive:", "embed:", "re-identify:", "reconstruct",
                  "picture:"):
        assert f"] {stage}" in progress, stage
    for name in ("recording/meta.json", "sightings.db", "sightings.csv", "truth.csv",
                 "estimate_shortest-path.csv", "estimate_hmm.csv", "summary.json",
                 "trajectory.png"):
        assert (out / name).is_file(), name
    s = json.loads((out / "summary.json").read_text())
    assert s["config"]["sightings"] == "vision" and s["config"]["detector"] == "shipped"
    assert s["config"]["every_s"] == 0.2 and s["config"]["image_size"] == [640, 360]
    # the accepted tracks' detections out to 20 m join the route (--route-range's default)
    assert s["config"]["route_m"] == 20.0 and s["route_sightings_beyond"] >= 0
    if s["route_sightings_beyond"]:
        assert (f"{s['route_sightings_beyond']} of them beyond 15 m, within the route range "
                "20 m") in printed
    # the threshold and recipe are the ones calibrated on training recordings, beside the
    # shipped model
    th = load_threshold(shipped_model_path())
    assert s["reid_threshold"] == th.calibration.threshold
    assert s["reid_query"] == th.calibration.query
    assert {src["seed"] for src in th.provenance["sources"]}.isdisjoint(range(5))
    assert s["query"]["observer_id"] > 0 and s["reid_tracks"] >= 2
    # query expansion averaged those of its track's crops that the query crop accepts (none
    # when the query crop is too small or cut by the frame: then it stays the one crop)
    assert 0 <= s["reid_query_crops"]["used"] <= s["reid_query_crops"]["of"], s["reid_query_crops"]
    # it finds the target: every accepted track is the target's (the precision 1.0
    # on this run); how many of its tracks it finds depends on the models
    assert s["reid_true_matches"] >= 1
    assert s["reid_precision"] == 1.0 and s["reid_recall"] > 0.0
    # every missed track of the target has its cause
    assert sum(s["reid_misses_by_cause"].values()) == s["reid_misses"]
    assert set(s["reid_misses_by_cause"]) == {"threshold", "gate", "no_usable_crop"}
    assert s["sightings"] > 0 and set(s["methods"]) == {"shortest-path", "hmm"}
    assert s["methods"]["hmm"]["sspd_seen_m"] < 5.0
    # the one reconstruction path saw exactly the sightings written out
    (call,) = spy
    assert len(call["sightings"]) == s["sightings"]
    assert call["results"]["hmm"]["sspd_whole_m"] == s["methods"]["hmm"]["sspd_whole_m"]
    # the calibration command's mechanics on this database (a real threshold file comes
    # from training recordings: make reid-threshold)
    t = tmp_path / "t.json"
    assert main(["reid-threshold", str(out / "sightings.db"), "-o", str(t), "--rule", "far",
                 "--max-far", "0.05", "--max-queries", "100"]) == 0
    cal = load_threshold(shipped_model_path(), t)
    assert cal.calibration.rule == "far" and cal.calibration.positives > 0
    assert cal.calibration.query == "track" and cal.calibration.max_far == 0.05
    assert cal.provenance["sources"][0]["look"] == s["look"] == th.provenance["sources"][0]["look"]
    # negative evidence (--watch): what each camera looked at comes from the database, one
    # view per observer, a frame per pose, each box's bearings inside the field of view;
    # the watch only adds "two vehicles" pairs (the gate may then pick another consistent
    # set; on this run it keeps some of the same tracks), and every kept one is true
    from dashtraj.reid.embed import ReidEmbedder
    from dashtraj.reidentify.vision import camera_views, target_from_db
    from dashtraj.roads import RoadMap
    from dashtraj.store import SightingsDB
    from dashtraj.world.recording import Recording

    with SightingsDB.open(out / "sightings.db") as db:
        views = camera_views(db)
        poses = db.poses()
    assert len(views) == 3 and sum(len(v.t) for v in views) == len(poses)
    assert all(np.all(np.diff(v.t) > 0) for v in views)
    bearings = np.concatenate([b for v in views for b in v.boxes])
    assert len(bearings) and np.all(bearings[:, 0] <= bearings[:, 1])
    assert np.all(np.abs(bearings) <= 45.0 + 1e-9)
    rec = Recording.open(out / "recording")
    kw = dict(embedder=ReidEmbedder(shipped_model_path(), threads=1),
              threshold=th.calibration.threshold, recipe=th.calibration.recipe,
              route_m=20.0)
    db_copy = tmp_path / "copy.db"
    db_copy.write_bytes((out / "sightings.db").read_bytes())
    road_map = RoadMap.from_file(rec.map_path)
    vid = int(rec.meta["target_vehicle_id"])
    plain = target_from_db(db_copy, road_map, vid, watch=False, **kw)
    watched = target_from_db(db_copy, road_map, vid, watch=True, **kw)
    assert set(watched.true_match) <= set(plain.true_match)
    assert plain.summary["reid_true_matches"] == s["reid_true_matches"]
    assert watched.summary["reid_precision"] == 1.0
    # the look-alike rule only ever drops tracks the gate kept, and says how many
    ruled = target_from_db(db_copy, road_map, vid, lookalike=True, **kw)
    assert set(ruled.true_match) <= set(plain.true_match)
    assert len(plain.true_match) - len(ruled.true_match) == ruled.summary["reid_unlinked"]
    assert plain.summary["reid_lookalikes"] == plain.summary["reid_unlinked"] == 0


@pytest.mark.slow
def test_oracle_vision_and_ablation_share_one_reconstruction(tmp_path, gl_available, spy):
    from dashtraj.ablation import EXTRA_ROWS, ROWS, budget, run_ablation

    oracle = ex.run_experiment(ex.ExperimentConfig(**{**SMALL, "sightings": "oracle"}),
                               tmp_path / "o")
    assert len(spy) == 1 and spy[0]["results"] == oracle.summary["methods"]
    # the ablation with the oracle as "the detector": rows 1 and 2 are the same database
    # content, so real detection adds exactly nothing; the ReID row is the vision pipeline
    res = run_ablation(ex.ExperimentConfig(**{**SMALL, "sightings": "vision",
                                              "reid": "appearance"}), tmp_path / "a")
    assert len(spy) == 1 + len(ROWS) + len(EXTRA_ROWS)
    rows = res["rows"]
    assert rows["oracle"]["methods"] == rows["detection"]["methods"]
    assert rows["vision-oracle-detector"] == rows["reid"]  # the "model" is the oracle here
    assert rows["oracle"]["reid_precision"] == 1.0 and rows["reid"]["sightings"] > 0
    assert all(rows[r[0]]["sightings"] > 0 for r in ROWS)
    b = budget([res])["hmm"]
    assert b["impact"]["detection"]["sspd_whole_m"] == 0.0
    assert b["rows"]["reid"]["sspd_whole_m"] == pytest.approx(
        rows["reid"]["methods"]["hmm"]["sspd_whole_m"])
    assert (tmp_path / "a" / "ablation.json").is_file()


@pytest.mark.slow
def test_the_localizer_is_chosen_by_name(tmp_path, gl_available):
    """`experiments --localizer NAME` reaches perceive: the run's database records it, and
    the `mapped` localizer's positions differ from the default `smoothed` ones."""
    from dashtraj.store import SightingsDB

    xy = {}
    for name in ("smoothed", "mapped"):
        cfg = ex.ExperimentConfig(**{**SMALL, "sightings": "detections", "every_s": 0.5,
                                     "localizer": name})
        res = ex.run_experiment(cfg, tmp_path / name)
        assert res.summary["sightings"] > 0
        assert ex.ExperimentConfig.from_dict(res.summary["config"]).localizer == name
        with SightingsDB.open(tmp_path / name / "sightings.db") as db:
            assert db.run_info()["config"]["localizer"] == name
            xy[name] = [(d.x, d.y) for d in db.detections()]
    assert len(xy["smoothed"]) == len(xy["mapped"]) and xy["smoothed"] != xy["mapped"]
