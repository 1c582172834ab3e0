"""Experiments: the issue's summary keys, ReID figures, twins, and the detections source."""

from __future__ import annotations

import argparse
import json

import pytest

import dashtraj.perception.pipeline as pipeline
from dashtraj.cli import main
from dashtraj.cli._vision_args import add_vision_args, vision_settings
from dashtraj.experiments import (
    ExperimentConfig,
    ExperimentError,
    aggregate_reid,
    perceive_run,
    plot_experiment,
    run_experiment,
    target_sightings,
)

KEYS = ("sspd_whole_m", "sspd_seen_m", "hausdorff_whole_m", "hausdorff_seen_m")


def test_json_has_the_issues_keys_per_experiment_and_mean(tmp_path, capsys):
    assert main(["experiments", "--sightings", "oracle", "--towns", "town01", "--seeds", "2-2",
                 "--twins", "2", "--json", "-o", str(tmp_path / "x")]) == 0
    out = json.loads(capsys.readouterr().out)
    (e,) = out["experiments"]
    assert e["experiment"] == "town01_seed2"
    assert set(e["methods"]) == {"shortest-path", "hmm"}
    for m in ("shortest-path", "hmm"):
        assert set(e["methods"][m]) == set(KEYS)
        assert out["mean"]["methods"][m] == e["methods"][m]  # one experiment: mean == it
    # oracle sightings are the target's by construction
    assert e["reid_precision"] == 1.0 and e["reid_recall"] == 1.0
    assert out["mean"]["reid_precision"] == 1.0 and out["mean"]["experiments"] == 1
    s = json.loads((tmp_path / "x" / "town01_seed2" / "summary.json").read_text())
    assert s["config"]["twins"] == 2 and s["vehicles"] == 1 + 4 + 20 + 2
    hmm = s["methods"]["hmm"]
    assert hmm["sspd_whole_m"] == hmm["sspd_m"] and hmm["hausdorff_seen_m"] == \
        hmm["seen_hausdorff_m"]
    assert s["reid_true_matches"] == s["target_tracks"] > 0 and s["reid_false_matches"] == 0
    meta = json.loads((tmp_path / "x" / "town01_seed2" / "recording" / "meta.json").read_text())
    assert meta["twin_vehicle_ids"] == [25, 26]


def test_reid_pooled_over_experiments():
    rows = [{"reid_true_matches": 9, "reid_false_matches": 0, "reid_misses": 1},
            {"reid_true_matches": 0, "reid_false_matches": 1, "reid_misses": 0}]
    r = aggregate_reid(rows)
    assert r["reid_precision"] == pytest.approx(0.9) and r["reid_recall"] == pytest.approx(0.9)


def test_config_round_trip_and_bad_source():
    cfg = ExperimentConfig(sightings="detections", twins=3, image_size=(320, 180))
    assert ExperimentConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
    with pytest.raises(ExperimentError, match="unknown sightings source 'pixels'; valid: oracle"):
        ExperimentConfig(sightings="pixels")
    with pytest.raises(ExperimentError, match="unknown localizer 'kalman'; valid: paper, "):
        ExperimentConfig(sightings="vision", reid="appearance", localizer="kalman")
    assert ExperimentConfig(localizer="mapped").localizer == "mapped"
    vis = ExperimentConfig(sightings="vision", reid="appearance", detector="oracle",
                           reid_threshold="t.json", look="flat", every_s=0.2,
                           agnostic_nms_iou=None, min_score=0.45, confirm_score=0.6)
    assert ExperimentConfig.from_dict(json.loads(json.dumps(vis.to_dict()))) == vis
    # a summary written before the box filters were settings: the defaults of the time
    # (before the tracker's confirmation rule every track with min_hits hits was reported)
    old = {k: v for k, v in vis.to_dict().items()
           if k not in ("agnostic_nms_iou", "min_score", "confirm_score")}
    back = ExperimentConfig.from_dict(old)
    assert (back.agnostic_nms_iou, back.min_score, back.confirm_score) == (0.45, 0.25, 0.0)
    assert ExperimentConfig().confirm_score == 0.5


@pytest.fixture
def perceived(monkeypatch):
    """`pipeline.perceive` replaced by a recorder: the list of the `PerceiveConfig`s it
    was called with (the perception itself is tested in tests/perception)."""
    seen = []

    class Summary:
        frames = detections = tracks = crops = 0

    def fake_perceive(rec, db_path, config, workers=1, progress=None):
        seen.append(config)
        return Summary()

    monkeypatch.setattr(pipeline, "perceive", fake_perceive)
    return seen


def vision_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser()
    add_vision_args(ap, default_sightings="vision")
    return ap


ONE_OBSERVER = argparse.Namespace(meta={"observer_ids": [1], "simulated_to_t": 1.0})


def test_box_filters_reach_the_perception(perceived, tmp_path):
    """``experiments --min-score`` / ``--agnostic-nms`` go into the run's config and from
    there into `PerceiveConfig`."""
    ap = vision_parser()
    for argv, want in (([], (0.45, 0.25, 0.5)),
                       (["--min-score", "0.45", "--agnostic-nms", "none", "--confirm-score", "0"],
                        (None, 0.45, 0.0))):
        cfg = ExperimentConfig(reid="appearance", **vision_settings(ap.parse_args(argv)))
        assert (cfg.agnostic_nms_iou, cfg.min_score, cfg.confirm_score) == want
        perceive_run(cfg, ONE_OBSERVER, tmp_path / "x.db", "shipped")
        assert (perceived[-1].agnostic_nms_iou, perceived[-1].min_score,
                perceived[-1].confirm_score) == want


def test_detections_source_takes_the_runs_perception_settings(monkeypatch, tmp_path):
    """``--sightings detections`` perceives with the run's frame period, box filters,
    confirmation rule and look, as ``vision`` does (it once took perceive's defaults, so
    ``--every 0.5`` was silently ignored there)."""
    seen = []

    class Seen(Exception):
        pass

    def fake_perceive(rec, db_path, config, workers=1, progress=None):
        seen.append(config)
        raise Seen

    monkeypatch.setattr(pipeline, "perceive", fake_perceive)
    rec = argparse.Namespace(meta={"observer_ids": [1, 2], "simulated_to_t": 4.0,
                                   "target_vehicle_id": 0})
    args = vision_parser().parse_args(["--sightings", "detections", "--every", "0.5",
                                       "--confirm-score", "0.7", "--min-score", "0.3",
                                       "--look", "flat", "--size", "320x180"])
    cfg = ExperimentConfig(**vision_settings(args))
    with pytest.raises(Seen):
        target_sightings(cfg, rec, tmp_path, road_map=None)
    (pc,) = seen
    assert pc.detector == "oracle" and pc.every_s == 0.5 and pc.size == (320, 180)
    assert (pc.confirm_score, pc.min_score, pc.look) == (0.7, 0.3, "flat")
    assert pc.reid_range_m == cfg.max_distance_m == 15.0


def test_gallery_range_reaches_perception_and_is_checked(perceived, tmp_path):
    """``--gallery-range``: a vision setting that perception's crop range follows; refused
    with other sources and under the query's range (ExperimentError: exit 2 at the CLI)."""
    ap = vision_parser()
    for argv, want, crops in (([], None, 15.0), (["--gallery-range", "25"], 25.0, 25.0)):
        cfg = ExperimentConfig(reid="appearance", **vision_settings(ap.parse_args(argv)))
        assert cfg.gallery_m == want
        assert ExperimentConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
        perceive_run(cfg, ONE_OBSERVER, tmp_path / "x.db", "shipped")
        assert perceived[-1].reid_range_m == crops
    with pytest.raises(ExperimentError, match="--gallery-range 10.0: must be a number of "
                                              r"metres, at least the query's range \(15 m\)"):
        ExperimentConfig(sightings="vision", reid="appearance", gallery_m=10.0)
    with pytest.raises(ExperimentError, match="needs --sightings vision"):
        ExperimentConfig(sightings="detections", gallery_m=30.0)
    # a summary written before the settings reads as the paper's gallery and route
    old = {k: v for k, v in ExperimentConfig(sightings="vision", reid="appearance")
           .to_dict().items() if k not in ("gallery_m", "route_m")}
    back = ExperimentConfig.from_dict(old)
    assert back.gallery_m is None and back.route_m is None


def test_route_range_is_a_vision_setting_at_least_the_gallerys():
    ap = vision_parser()
    cfg = ExperimentConfig(reid="appearance",
                           **vision_settings(ap.parse_args(["--route-range", "30"])))
    assert cfg.route_m == 30.0 and cfg.gallery_m is None
    # the default: 20 m from pixels (or the gallery's range where farther), none otherwise
    for argv, want in (([], 20.0), (["--gallery-range", "25"], 25.0),
                       (["--route-range", "15"], 15.0), (["--sightings", "detections"], None),
                       (["--sightings", "oracle"], None)):
        assert vision_settings(ap.parse_args(argv))["route_m"] == want, argv
    assert ExperimentConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
    with pytest.raises(ExperimentError, match=r"--route-range 20.0: must be a number of "
                                              r"metres, at least the gallery's range \(25 m\)"):
        ExperimentConfig(sightings="vision", reid="appearance", gallery_m=25.0, route_m=20.0)
    with pytest.raises(ExperimentError, match=r"--route-range adds .* needs --sightings vision"):
        ExperimentConfig(sightings="detections", route_m=20.0)


def test_watch_is_a_vision_setting():
    ap = vision_parser()
    for argv, want in (([], None), (["--watch"], True), (["--no-watch"], False)):
        assert vision_settings(ap.parse_args(argv))["watch"] is want, argv
    cfg = ExperimentConfig(reid="appearance", **vision_settings(ap.parse_args(["--watch"])))
    assert cfg.watch is True
    assert ExperimentConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
    with pytest.raises(ExperimentError, match=r"--watch .* needs --sightings vision"):
        ExperimentConfig(sightings="oracle", watch=True)


def test_lookalike_is_a_vision_setting():
    ap = vision_parser()
    for argv, want in (([], None), (["--lookalike"], True), (["--no-lookalike"], False)):
        assert vision_settings(ap.parse_args(argv))["lookalike"] is want, argv
    cfg = ExperimentConfig(reid="appearance",
                           **vision_settings(ap.parse_args(["--no-lookalike"])))
    assert cfg.lookalike is False
    assert ExperimentConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
    with pytest.raises(ExperimentError, match=r"--lookalike .* needs --sightings vision"):
        ExperimentConfig(sightings="oracle", lookalike=False)


@pytest.mark.slow
def test_detections_source_from_pixels(tmp_path):
    # A short run from rendered frames: perceive (oracle detector, ego tracker, fused
    # localizer) into sightings.db, the target's tracks picked by true identity, then
    # the same reconstruction and scoring as the oracle source.
    cfg = ExperimentConfig(town="town01", seed=2, observers=2, agents=4, duration_s=30.0,
                           sightings="detections", image_size=(256, 144))
    res = run_experiment(cfg, tmp_path)
    s = res.summary
    for name in ("sightings.db", "sightings.csv", "truth.csv", "estimate_hmm.csv",
                 "estimate_shortest-path.csv", "summary.json"):
        assert (tmp_path / name).is_file(), name
    assert s["sightings"] > 0 and s["target_tracks"] >= 1
    assert s["reid_precision"] == 1.0 and s["reid_recall"] == 1.0  # by construction
    assert set(s["methods"]) == {"shortest-path", "hmm"}
    # every sighting used comes from a track whose truth is the target
    from dashtraj.reidentify.scoring import truth_of_tracks
    from dashtraj.store import SightingsDB

    with SightingsDB.open(tmp_path / "sightings.db") as db:
        truth = truth_of_tracks(db, 15.0)
    assert all(truth[(x.observer_id, x.track_id)] == 0 for x in res.sightings)
    assert s["methods"]["hmm"]["sspd_seen_m"] < 5.0


def test_look_alikes_gate_raises_precision(tmp_path):
    # three exact twins of the target; appearance that cannot tell them apart accepts
    # every twin track it saw; the gate drops those the target could not have made
    # (town01, seed 0: 11 candidate tracks, 6 of them the target's)
    res = {}
    for gate in (False, True):
        cfg = ExperimentConfig(town="town01", seed=0, twins=3, reid="look-alike", gate=gate)
        res[gate] = run_experiment(cfg, tmp_path / str(gate))
    off, on = res[False].summary, res[True].summary
    assert off["reid_candidates"] == on["reid_candidates"] == 11
    assert (off["reid_true_matches"], off["reid_false_matches"]) == (6, 5)
    assert off["reid_gated_out"] == 0
    assert (on["reid_true_matches"], on["reid_false_matches"], on["reid_misses"]) == (6, 0, 0)
    assert on["reid_precision"] == 1.0 and on["reid_gated_out"] == 5
    assert on["methods"]["hmm"]["sspd_whole_m"] < off["methods"]["hmm"]["sspd_whole_m"]
    # the picture marks each used sighting's track as a true or a false match
    assert sorted(res[False].true_match.values()) == [False] * 5 + [True] * 6
    assert all(res[True].true_match.values())
    png = plot_experiment(res[False], tmp_path / "fig6.png")
    assert png.stat().st_size > 10_000
