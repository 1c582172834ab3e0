"""`dashtraj score` end to end through `dashtraj.cli.main`."""

from __future__ import annotations

import json
import math

import pytest

from dashtraj.cli import main


@pytest.fixture
def files(tmp_path):
    truth = tmp_path / "truth.csv"
    estimate = tmp_path / "estimate.csv"
    # Truth: L-shape; estimate: its diagonal. SSPD 5 sqrt(2)/6, Hausdorff 5 sqrt(2).
    truth.write_text("x,y,t\n0,0,0\n10,0,1\n10,10,2\n")
    estimate.write_text("x,y\n0,0\n10,10\n")
    return truth, estimate


def test_text_output(files, capsys):
    truth, estimate = files
    assert main(["score", "--truth", str(truth), "--estimate", str(estimate)]) == 0
    out = capsys.readouterr().out.strip()
    assert out == "SSPD 1.179 m  Hausdorff 7.071 m  (truth 3 points, estimate 2 points)"


def test_json_output(files, capsys):
    truth, estimate = files
    assert main(["score", "--truth", str(truth), "--estimate", str(estimate), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert got["sspd_m"] == pytest.approx(5 * math.sqrt(2) / 6, abs=1e-12)
    assert got["hausdorff_m"] == pytest.approx(5 * math.sqrt(2), abs=1e-12)
    assert (got["truth_points"], got["estimate_points"]) == (3, 2)


def test_resample_option(files, capsys):
    truth, estimate = files
    argv = ["score", "--truth", str(truth), "--estimate", str(estimate), "--json"]
    assert main([*argv, "--resample-m", "1"]) == 0
    got = json.loads(capsys.readouterr().out)
    # Hausdorff stays at the corner; with dense sampling SSPD becomes a path average.
    assert got["hausdorff_m"] == pytest.approx(5 * math.sqrt(2), abs=1e-9)
    assert (got["truth_points"], got["estimate_points"]) == (3, 2)
    assert got["sspd_m"] > 5 * math.sqrt(2) / 6


def test_bad_file_exits_2_with_located_message(files, tmp_path, capsys):
    truth, _ = files
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y\n0,0\n1,zz\n")
    assert main(["score", "--truth", str(truth), "--estimate", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "bad.csv line 3, column 'y': 'zz' is not a number" in err


def test_non_positive_resample_is_an_error(files, capsys):
    truth, estimate = files
    argv = ["score", "--truth", str(truth), "--estimate", str(estimate), "--resample-m", "0"]
    assert main(argv) == 2
    assert "--resample-m must be a positive" in capsys.readouterr().err
