"""scripts/reid_judge_table.py: the judge's files read back into one row per model."""

import hashlib
import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _load():
    spec = importlib.util.spec_from_file_location("reid_judge_table",
                                                  ROOT / "scripts" / "reid_judge_table.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _eval(rank1, mAP):
    # the keys `dashtraj reid eval --json` prints (and more the table does not read)
    return {"rank1": rank1, "rank5": 0.99, "rank10": 1.0, "map": mAP, "minp": 0.7,
            "queries": 422, "gallery": 3828}


def _rescore(true, false, missed, whole, seen):
    # the shape of `scripts/reid_rescore.py --json`
    p = true / (true + false)
    return {"model": "m.onnx", "threshold": 0.4, "runs": [],
            "methods": {"hmm": {"sspd_whole_m": whole, "sspd_seen_m": seen,
                                "hausdorff_seen_m": 1.0},
                        "shortest-path": {"sspd_whole_m": 9.0, "sspd_seen_m": 8.0,
                                          "hausdorff_seen_m": 20.0}},
            "reid": {"reid_precision": p, "reid_recall": true / (true + missed),
                     "reid_true_matches": true, "reid_false_matches": false,
                     "reid_misses": missed}}


def test_rows_figures_and_missing_ones(tmp_path, capsys):
    mod = _load()
    sha = mod.shipped_sha256()
    assert sha == hashlib.sha256((ROOT / "src/dashtraj/data/reid/efficientnet_lite0_cpu.onnx")
                                 .read_bytes()).hexdigest()
    cand = tmp_path / "models" / "cand_0123456789ab"
    shipped = tmp_path / "models" / f"efficientnet_lite0_cpu_{sha[:12]}"
    for f in (cand, shipped):
        f.mkdir(parents=True)
    (shipped / "ring.json").write_text(json.dumps(_eval(0.9763, 0.9443)))
    (shipped / "model.threshold.json").write_text(
        json.dumps({"calibration": {"threshold": 0.40834}}))
    (shipped / "e2e_ten_twins.json").write_text(json.dumps(_rescore(56, 8, 4, 5.27, 4.41)))
    (cand / "moving.json").write_text(json.dumps(_eval(0.925, 0.886)))
    (cand / "ring99.json").write_text("{not json")  # a half-written file reads as missing

    assert mod.main([str(tmp_path), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["name"] for r in rows] == [shipped.name, cand.name]  # the shipped model first
    assert rows[0]["shipped"] and not rows[1]["shipped"]
    assert rows[0]["threshold"] == pytest.approx(0.40834)
    assert rows[0]["ten_twins"] == {"true": 56, "false": 8, "missed": 4, "precision": 0.875,
                                    "recall": pytest.approx(56 / 60),
                                    "hmm_sspd_whole_m": 5.27, "hmm_sspd_seen_m": 4.41}
    assert rows[1]["moving"]["rank1"] == 0.925 and rows[1]["ring99"] is None

    assert mod.main([str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("| model | threshold | ring | moving |")
    first = lines[2].split(" | ")
    assert first[0] == f"| {shipped.name} (shipped)" and first[1] == "0.4083"
    assert first[2] == "97.6 / 94.4" and first[3] == "—"
    assert "56 / 8 / 4 (0.875); hmm 5.27 / 4.41 m" in lines[2]
    assert lines[3].split(" | ")[3] == "92.5 / 88.6"


def test_no_models_is_exit_2(tmp_path, capsys):
    assert _load().main([str(tmp_path)]) == 2
    assert "no models measured" in capsys.readouterr().err
