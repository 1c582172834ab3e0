"""End-to-end experiments: simulate → sightings → reconstruct → score, on built-in towns."""

from __future__ import annotations

import json

import pytest

from dashtraj.cli import main
from dashtraj.experiments import ExperimentConfig, aggregate, run_experiment


@pytest.fixture(scope="module")
def town01_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("exp")
    cfg = ExperimentConfig(town="town01", seed=2, agents=8)
    return cfg, out, run_experiment(cfg, out)


def test_experiment_writes_its_files_and_scores_both_methods(town01_run):
    cfg, out, _ = town01_run
    for name in ("sightings.csv", "truth.csv", "estimate_hmm.csv",
                 "estimate_shortest-path.csv", "summary.json", "recording/meta.json"):
        assert (out / name).is_file(), name
    s = json.loads((out / "summary.json").read_text())
    assert ExperimentConfig.from_dict(s["config"]) == cfg
    assert s["sightings"] > 0 and s["observers_that_saw_target"] >= 2
    hmm = s["methods"]["hmm"]
    # On the stretch the sightings cover, the HMM follows the true route closely.
    assert hmm["seen_sspd_m"] < 1.0
    assert hmm["seen_sspd_m"] <= s["methods"]["shortest-path"]["seen_sspd_m"] + 1e-9
    assert s["seen_route_m"] <= s["true_route_m"] + 1e-6


def test_same_seed_same_scores(town01_run, tmp_path):
    cfg, out, res = town01_run
    again = run_experiment(cfg, tmp_path)
    assert again.summary["methods"] == res.summary["methods"]
    assert (tmp_path / "sightings.csv").read_bytes() == (out / "sightings.csv").read_bytes()


def test_aggregate_means():
    rows = [{"methods": {"hmm": {"sspd_m": 1.0, "hausdorff_m": 4.0, "seen_sspd_m": 0.5,
                                 "seen_hausdorff_m": 2.0}}},
            {"methods": {"hmm": {"sspd_m": 3.0, "hausdorff_m": 8.0, "seen_sspd_m": 1.5,
                                 "seen_hausdorff_m": 4.0}}}]
    a = aggregate(rows)["hmm"]
    assert a["experiments"] == 2
    assert a["mean_sspd_m"] == 2.0 and a["mean_seen_hausdorff_m"] == 3.0


def test_demo_command(tmp_path, capsys):
    assert main(["demo", "--sightings", "oracle", "--town", "town01", "--seed", "2",
                 "--agents", "8", "-q", "-o", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert "sightings of the target" in text and "hmm" in text
    assert (tmp_path / "trajectory.png").stat().st_size > 10_000
    assert json.loads((tmp_path / "summary.json").read_text())["picture"].endswith(".png")
