"""`dashtraj reid moving-queries` adds the moving-observer query set to a ReID set."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

from dashtraj.cli import main
from dashtraj.datasets.reid import (
    NAME_PATTERN,
    ReidConfig,
    build_reid_dataset,
    read_moving_labels,
)
from dashtraj.world.camera import CameraSpec
from dashtraj.world.recording import RunConfig, simulate


def test_moving_queries_command(gl_available, tmp_path, capsys):
    cfg = ReidConfig(n_ids=40, n_test_ids=30, n_cameras=2, size=32, fov_deg=None)
    build_reid_dataset(cfg, tmp_path / "set")
    run = RunConfig(map="town10", seed=5, duration_s=8.0, n_observers=2, n_agents=8,
                    identity_range=(10, 40), camera=CameraSpec(width_px=640, height_px=360))
    simulate(run, tmp_path / "rec")
    args = ["reid", "moving-queries", str(tmp_path / "set"), str(tmp_path / "rec"),
            "--every", "0.5", "--json"]
    assert main(args) == 0
    counts = json.loads(capsys.readouterr().out)
    files = sorted(p.name for p in (tmp_path / "set" / "image_query_moving").iterdir())
    assert files == (tmp_path / "set" / "name_query_moving.txt").read_text().split()
    assert counts["images"] == len(files) > 0
    assert all(re.match(NAME_PATTERN, n) and 11 <= int(n[:4]) <= 40 and int(n[6:9]) > 2
               for n in files)
    info = json.loads((tmp_path / "set" / "reid.json").read_text())
    assert info["counts"]["query_moving"] == counts and len(info["moving_cameras"]) == 2
    # every crop's exact labels beside it: its vehicle's share outside the frame, its
    # visible fraction (the set's rule keeps >= 0.6) and its box (>= 24 px high)
    labels = read_moving_labels(tmp_path / "set" / "labels_query_moving.csv")
    assert sorted(labels) == files
    assert all(0 <= t <= 1 and 0.6 <= v <= 1 and w > 0 and h >= 24
               for t, v, w, h in labels.values())
    whole = sum(t == 0 for t, *_ in labels.values())
    assert 0 < whole < len(files)  # both kinds in this recording
    # reid eval keeps the queries within a truncation, and says how many it left out
    ev = ["reid", "eval", "--data", str(tmp_path / "set"), "--query", "image_query_moving",
          "--threads", "1", "--json"]
    assert main([*ev, "--max-truncation", "0"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["max_truncation"] == 0 and out["truncated_queries_left_out"] == len(files) - whole
    assert out["queries"] + out["skipped_queries"] == whole
    assert main(ev) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["max_truncation"] is None and out["truncated_queries_left_out"] == 0
    assert out["queries"] + out["skipped_queries"] == len(files)
    # the ring's queries have no labels; a bad labels file is named with its line
    assert main([*ev[:5], "image_query", "--max-truncation", "0.5", "--json"]) == 2
    assert "labels_query.csv is missing" in capsys.readouterr().err
    lab = tmp_path / "set" / "labels_query_moving.csv"
    good = lab.read_text()
    lab.write_text(good.replace(",", ";", 2))
    assert main([*ev, "--max-truncation", "0.5"]) == 2
    assert "labels_query_moving.csv: line 1: the header" in capsys.readouterr().err
    lines = good.splitlines()
    lab.write_text("\n".join([lines[0], lines[1].rsplit(",", 1)[0] + ",x", *lines[2:]]) + "\n")
    assert main([*ev, "--max-truncation", "0.5"]) == 2
    assert "labels_query_moving.csv: line 2: bad row" in capsys.readouterr().err
    lab.write_text("\n".join(lines[:-1]) + "\n")
    assert main([*ev, "--max-truncation", "0.5"]) == 2
    assert "no row for " + lines[-1].split(",")[0] in capsys.readouterr().err
    lab.write_text(good)
    assert main(args) == 2  # an existing query set is kept unless --overwrite
    assert "--overwrite" in capsys.readouterr().err
    assert main([*args, "--overwrite"]) == 0
    assert lab.read_text() == good  # the same labels again


def test_moving_train_command(gl_available, tmp_path, capsys, monkeypatch):
    # ids 1-10 train, 11-40 test; the recordings draw identities 0-13 (ids 1-14)
    cfg = ReidConfig(n_ids=40, n_test_ids=30, n_cameras=2, size=32, fov_deg=None)
    build_reid_dataset(cfg, tmp_path / "set")
    shutil.copytree(tmp_path / "set", tmp_path / "set2")
    shutil.copytree(tmp_path / "set", tmp_path / "set3")
    recs = []
    for seed in (5, 2):  # seed 5's observers see only test ids, seed 2's training ids
        run = RunConfig(map="town10", seed=seed, duration_s=8.0, n_observers=2, n_agents=8,
                        identity_range=(0, 14), camera=CameraSpec(width_px=640, height_px=360))
        simulate(run, tmp_path / f"rec{seed}")
        recs.append(str(tmp_path / f"rec{seed}"))
    args = ["reid", "moving-train", str(tmp_path / "set"), *recs, "--every", "0.5", "--json"]
    assert main(args) == 0
    counts = json.loads(capsys.readouterr().out)
    files = sorted(p.name for p in (tmp_path / "set" / "image_train_moving").iterdir())
    assert files == (tmp_path / "set" / "name_train_moving.txt").read_text().split()
    assert counts["images"] == len(files) > 0 and counts["skipped_not_train"] > 0
    # training identities only, on cameras numbered from 500
    assert all(re.match(NAME_PATTERN, n) and 1 <= int(n[:4]) <= 10 and int(n[6:9]) >= 500
               for n in files)
    info = json.loads((tmp_path / "set" / "reid.json").read_text())
    assert info["counts"]["train_moving"] == counts
    assert len(info["train_moving"]["cameras"]) == 4 and "moving_cameras" not in info
    assert not (tmp_path / "set" / "image_query_moving").exists()
    assert main(args) == 2
    assert "--overwrite" in capsys.readouterr().err
    # the same crops in two steps: seed 5's recording, then seed 2's appended; cameras and
    # recording numbers continue, so files, list and reid.json equal the one-step set's
    step = ["reid", "moving-train", str(tmp_path / "set2"), "--every", "0.5", "--json"]
    assert main([*step, "--append", recs[0]]) == 2  # nothing to append to yet
    assert "without --append" in capsys.readouterr().err
    assert main([*step, recs[0]]) == 0
    assert json.loads(capsys.readouterr().out)["images"] == 0
    # a set made before the crops' labels (2026-12-07) gets none on --append, not half
    shutil.copytree(tmp_path / "set2", tmp_path / "set4")
    (tmp_path / "set4" / "labels_train_moving.csv").unlink()
    assert main(["reid", "moving-train", str(tmp_path / "set4"), "--every", "0.5", "--json",
                 "--append", recs[1]]) == 0
    assert json.loads(capsys.readouterr().out) == counts
    assert not (tmp_path / "set4" / "labels_train_moving.csv").exists()
    assert main([*step, "--append", recs[1]]) == 0
    assert json.loads(capsys.readouterr().out) == counts
    one, two = tmp_path / "set" / "image_train_moving", tmp_path / "set2" / "image_train_moving"
    assert sorted(p.name for p in two.iterdir()) == files
    assert all((one / n).read_bytes() == (two / n).read_bytes() for n in files)
    assert ((tmp_path / "set2" / "name_train_moving.txt").read_text()
            == (tmp_path / "set" / "name_train_moving.txt").read_text())
    assert ((tmp_path / "set2" / "labels_train_moving.csv").read_bytes()
            == (tmp_path / "set" / "labels_train_moving.csv").read_bytes())
    assert sorted(read_moving_labels(tmp_path / "set" / "labels_train_moving.csv")) == files
    info2 = json.loads((tmp_path / "set2" / "reid.json").read_text())
    assert info2["train_moving"] == info["train_moving"]
    assert info2["counts"]["train_moving"] == counts
    # two recordings rendered at once in two processes: the same bytes
    three = tmp_path / "set3"
    assert main(["reid", "moving-train", str(three), *recs, "--every", "0.5", "--json",
                 "--workers", "2"]) == 0
    assert json.loads(capsys.readouterr().out) == counts
    assert sorted(p.name for p in (three / "image_train_moving").iterdir()) == files
    assert all((one / n).read_bytes() == (three / "image_train_moving" / n).read_bytes()
               for n in files)
    assert (three / "reid.json").read_bytes() == (tmp_path / "set" / "reid.json").read_bytes()
    assert main([*step, "--append", recs[1]]) == 2  # a recording already in the set
    assert "already in" in capsys.readouterr().err
    assert main([*step, "--append", "--every", "1", recs[1]]) == 2
    assert "sampled every 0.5" in capsys.readouterr().err
    assert sorted(p.name for p in two.iterdir()) == files  # refusals changed nothing
    # an interruption while the new set is moved in (here when reid.json, the last of the
    # folder, its name list and reid.json, is replaced) leaves all three as they were
    before = {p.name: (sorted(q.name for q in p.iterdir()) if p.is_dir() else p.read_bytes())
              for p in (tmp_path / "set2").iterdir()}
    rename = Path.rename

    def interrupted(self, target):
        if Path(target).name == "reid.json" and self.parent.name.startswith(".moving-"):
            raise KeyboardInterrupt  # the staged reid.json's move, not the restore
        return rename(self, target)

    monkeypatch.setattr(Path, "rename", interrupted)
    assert main([*step, "--overwrite", recs[0]]) == 130
    monkeypatch.setattr(Path, "rename", rename)
    after = {p.name: (sorted(q.name for q in p.iterdir()) if p.is_dir() else p.read_bytes())
             for p in (tmp_path / "set2").iterdir()}
    assert after == before  # no staged or backup folder left either
