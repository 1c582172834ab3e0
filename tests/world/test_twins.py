"""Look-alikes: `RunConfig.n_twins` / `dashtraj simulate --twins N`."""

from __future__ import annotations

import hashlib
import json

import pytest

from dashtraj.cli import main
from dashtraj.world.recording import Recording, RecordingError, RunConfig, simulate

FILES = ("meta.json", "vehicles.csv", "states.parquet", "truth.parquet", "target_route.csv")


@pytest.fixture(autouse=True)
def _town_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("DASHTRAJ_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


def test_twins_have_the_targets_model_and_colour(tmp_path):
    cfg = RunConfig(map="town01", seed=3, duration_s=5.0, n_observers=2, n_agents=6, n_twins=3)
    s = simulate(cfg, tmp_path / "r")
    rec = Recording.open(tmp_path / "r")
    assert s.vehicles == 1 + 2 + 6 + 3
    target = rec.vehicle(0)
    twins = [rec.vehicle(i) for i in rec.meta["twin_vehicle_ids"]]
    assert rec.meta["twin_vehicle_ids"] == [9, 10, 11]
    keys = ("identity_id", "blueprint_id", "color", "vehicle_class", "length_m", "height_m")
    for tw in twins:
        assert tw["role"] == "agent"
        assert {k: tw[k] for k in keys} == {k: target[k] for k in keys}
    # nobody else looks like the target, and the others are the vehicles of a run
    # without twins (identities drawn first, from the same seed)
    others = [v for v in rec.vehicles if v["vehicle_id"] not in (0, 9, 10, 11)]
    assert all(v["identity_id"] != target["identity_id"] for v in others)
    simulate(RunConfig(map="town01", seed=3, duration_s=5.0, n_observers=2, n_agents=6),
             tmp_path / "plain")
    plain = Recording.open(tmp_path / "plain")
    assert [v["identity_id"] for v in plain.vehicles] == \
        [v["identity_id"] for v in rec.vehicles[:9]]
    assert plain.meta["twin_vehicle_ids"] == []
    # the twins drive: each has a state at every step
    vid = rec.states.column("vehicle_id").to_pylist()
    assert all(vid.count(i) == s.frames for i in (9, 10, 11))
    assert rec.config == cfg


def test_twins_same_seed_same_bytes_via_cli(tmp_path, capsys):
    for name in ("a", "b"):
        assert main(["simulate", "--town", "town01", "--seed", "5", "--observers", "2",
                     "--agents", "4", "--twins", "2", "--duration", "4", "-q",
                     "-o", str(tmp_path / name)]) == 0
    digest = {n: {f: hashlib.sha256((tmp_path / n / f).read_bytes()).hexdigest()
                  for f in FILES} for n in ("a", "b")}
    assert digest["a"] == digest["b"]
    meta = json.loads((tmp_path / "a" / "meta.json").read_text())
    assert meta["config"]["n_twins"] == 2 and meta["twin_vehicle_ids"] == [7, 8]
    assert "9 vehicles" in capsys.readouterr().out


def test_bad_twins(tmp_path, capsys):
    with pytest.raises(RecordingError, match="n_twins must be an integer >= 0"):
        simulate(RunConfig(map="town01", n_twins=-1), tmp_path / "x")
    assert main(["simulate", "--twins", "-2", "-o", str(tmp_path / "y")]) == 2
    assert "--twins" in capsys.readouterr().err
