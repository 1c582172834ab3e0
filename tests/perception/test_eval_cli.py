"""`dashtraj tracker eval`, `localization eval` and `localization calibrate` on a small run."""

from __future__ import annotations

import json
from pathlib import Path

from dashtraj.cli import main
from dashtraj.perception.track import Relink


def test_tracker_eval_json_has_the_metrics_per_tracker(small_run, gl_available, capsys):
    assert main(["tracker", "eval", str(small_run.path), "--every", "0.2", "--peers",
                 "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["sequences"] == 3 and r["frames"] == 3 * 126
    assert r["detector"] == "oracle" and r["agnostic_nms"] is None  # no NMS on exact boxes
    assert r["min_score"] is None and r["confirm_score"] == 0.5  # the oracle's boxes score 1
    for n in ("sort", "ego"):
        assert {"idf1", "hota", "mota", "updates_per_s"} <= set(r[n])
        assert 0.0 <= r[n]["mota"] <= 1.0 and 0.0 <= r[n]["hota"] <= 1.0
        assert r[n]["num_gt"] > 50
        # MOTChallenge-style ignore regions (boxes < 20 px high at 720 rows, scaled to
        # the image but never under the oracle's 8 px, or < 30 % visible): no more truth
        # boxes, the same tracker output minus the boxes on them
        ig = r[n]["ignore_regions"]
        assert {"idf1", "hota", "mota"} <= set(ig)
        assert 0 < ig["num_gt"] <= r[n]["num_gt"]
        assert ig["num_tracked"] <= r[n]["num_tracked"]
    assert r["ego"]["idf1"] >= 0.8
    assert r["ego"]["idf1"] >= r["sort"]["idf1"]
    # offline confirmation: the same tracks, their first (min_hits - 1) boxes reported too
    off = r["ego+backfill"]
    assert "sort+backfill" not in r  # sort does not report unconfirmed tracks
    assert off["num_gt"] == r["ego"]["num_gt"]
    assert off["num_tracked"] > r["ego"]["num_tracked"]
    assert off["mota"] > r["ego"]["mota"] and off["idf1"] >= r["ego"]["idf1"]
    # and re-linked by appearance (tracks cut where their look changes, the tracks of one
    # vehicle that a gap split joined): on this short run nothing is cut or joined
    assert r["reid_model"].endswith(".onnx") and r["relink_cut"] == Relink().split_distance
    # the live re-linking embeds with the shipped model, the offline one with the join model
    assert Path(r["reid_model"]).name == "efficientnet_lite0_cpu.onnx"
    assert Path(r["relink_model"]).name == "efficientnet_lite0_join.onnx"
    # (and online, live: the same as it comes, `LiveRelink`)
    for n, base in (("ego+relink", r["ego"]), ("ego+backfill+relink", off),
                    ("ego+live-relink", r["ego"])):
        rl = r[n]
        assert rl["num_gt"] == base["num_gt"] and rl["num_tracked"] == base["num_tracked"]
        assert rl["idf1"] >= base["idf1"] >= 0.95


def test_localization_eval_json_and_scatter(small_run, gl_available, tmp_path, capsys):
    png = tmp_path / "scatter.png"
    # the sequential estimator fed every 0.5 s here (default 0.1 s) to keep the test short
    assert main(["localization", "eval", str(small_run.path), "--json", "--plot",
                 str(png), "--track-every", "0.5"]) == 0
    r = json.loads(capsys.readouterr().out)
    for n in ("paper", "ground", "fused", "tracked", "smoothed", "mapped"):
        assert {"rmse_lt20_m", "rmse_20_60_m", "median_lt20_m", "n_lt20"} <= set(r[n])
    assert r["mapped"]["n_lt20"] == r["smoothed"]["n_lt20"]
    assert r["mapped"]["rmse_lt20_m"] <= r["smoothed"]["rmse_lt20_m"] + 1e-9
    assert r["fused"]["rmse_lt20_m"] < 1.5  # 320 x 180 pixels
    assert r["agnostic_nms"] is None
    assert r["fused"]["rmse_lt20_m"] < r["paper"]["rmse_lt20_m"]
    assert r["tracked"]["rmse_lt20_m"] < r["paper"]["rmse_lt20_m"]
    assert r["smoothed"]["rmse_lt20_m"] < r["paper"]["rmse_lt20_m"]
    assert r["smoothed"]["n_lt20"] == r["tracked"]["n_lt20"] == r["paper"]["n_lt20"]
    # the detector protocol's ignore regions: the same detections less the tiny or mostly
    # hidden vehicles, the same for every estimator
    ign = {n: r[n]["ignore_regions"] for n in ("paper", "fused", "mapped")}
    assert ign["paper"]["n_lt20"] == ign["mapped"]["n_lt20"] <= r["paper"]["n_lt20"]
    assert 0 < ign["paper"]["n_20_60"] <= r["paper"]["n_20_60"]
    assert ign["fused"]["rmse_lt20_m"] <= 1.5
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["localization", "eval", str(small_run.path), "--plot", str(png)]) == 2


def test_calibrate_fits_a_constant_near_the_papers(small_run, gl_available, capsys):
    assert main(["localization", "calibrate", str(small_run.path), "-n", "30", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["n"] == 30 and r["height_px"] == 180
    assert 450.0 < r["mu_h_at_720"] < 750.0  # the paper's camera: 599.46
