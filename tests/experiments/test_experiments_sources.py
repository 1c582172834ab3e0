"""Experiments: the issue's summary keys, ReID figures, twins, and the detections source."""

from __future__ import annotations

import json

import pytest

from dashtraj.cli import main
from dashtraj.experiments import (
    ExperimentConfig,
    ExperimentError,
    aggregate_reid,
)

KEYS = ("sspd_whole_m", "sspd_seen_m", "hausdorff_whole_m", "hausdorff_seen_m")


def test_json_has_the_issues_keys_per_experiment_and_mean(tmp_path, capsys):
    assert main(["experiments", "--towns", "town01", "--seeds", "2-2", "--twins", "2", "--json",
                 "-o", str(tmp_path / "x")]) == 0
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
    with pytest.raises(ExperimentError, match="unknown sightings source 'vision'; valid: oracle"):
        ExperimentConfig(sightings="vision")
