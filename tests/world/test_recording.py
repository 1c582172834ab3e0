"""Recordings: byte-identical for a seed, config round trip, interrupted runs stay
readable, and clear errors for missing or corrupt parts."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from dashtraj.trajectory.io import read_trajectory
from dashtraj.world.recording import (
    IncompleteRecordingWarning,
    Recording,
    RecordingError,
    RunConfig,
    simulate,
)

FILES = ("meta.json", "vehicles.csv", "states.parquet", "truth.parquet",
         "target_route.csv", "map.xodr")


@pytest.fixture(autouse=True)
def _town_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("DASHTRAJ_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


def _digests(d: Path) -> dict[str, str]:
    return {f: hashlib.sha256((d / f).read_bytes()).hexdigest() for f in FILES}


def test_same_seed_byte_identical_files(tmp_path):
    cfg = RunConfig(map="town01", seed=7, duration_s=15.0, chunk_s=4.0)
    a = simulate(cfg, tmp_path / "a")
    simulate(cfg, tmp_path / "b")
    assert a.complete and a.frames == 301 and a.truth_rows > 0
    assert _digests(tmp_path / "a") == _digests(tmp_path / "b")
    c = simulate(RunConfig(map="town01", seed=8, duration_s=15.0, chunk_s=4.0), tmp_path / "c")
    assert c.complete
    assert _digests(tmp_path / "a")["states.parquet"] != _digests(tmp_path / "c")["states.parquet"]


def test_recording_reads_back(tmp_path):
    cfg = RunConfig(map="town10", seed=2, duration_s=10.0)
    s = simulate(cfg, tmp_path / "r")
    rec = Recording.open(tmp_path / "r")
    assert rec.complete and rec.config == cfg
    assert rec.states.num_rows == s.frames * s.vehicles
    assert rec.truth.num_rows == s.truth_rows
    assert {v["role"] for v in rec.vehicles} == {"target", "observer", "agent"}
    assert [v["role"] for v in rec.vehicles].count("observer") == 4
    assert len(rec.target_route) == s.frames
    assert read_trajectory(tmp_path / "r" / "target_route.csv") == rec.target_route
    meta = rec.meta
    assert meta["map"]["sha256"] == hashlib.sha256(rec.map_path.read_bytes()).hexdigest()
    labels = set(rec.truth.column("label").to_pylist())
    classes = {v["vehicle_class"] for v in rec.vehicles}
    assert all(lab.rsplit("_", 1)[0] in classes for lab in labels)


def test_config_json_round_trip():
    cfg = RunConfig(map="x.xodr", seed=3, target_route=((1.0, 2.0), (3.0, 4.0)))
    assert RunConfig.from_json(cfg.to_json()) == cfg
    assert json.loads(cfg.to_json())["camera"]["fov_deg"] == 90.0


def test_interrupted_run_leaves_readable_incomplete_recording(tmp_path):
    cfg = RunConfig(map="town01", seed=1, duration_s=60.0, chunk_s=5.0)

    def stop(t: float) -> None:
        if t >= 12.0:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        simulate(cfg, tmp_path / "r", progress=stop)
    with pytest.warns(IncompleteRecordingWarning, match=r"incomplete: simulated to t=12 s"):
        rec = Recording.open(tmp_path / "r")
    assert not rec.complete
    t = rec.states.column("t").to_pylist()
    assert max(t) == 12.0 and min(t) == 0.0
    assert rec.target_route.t[-1] == 12.0


def test_missing_and_corrupt_parts_are_named(tmp_path):
    simulate(RunConfig(map="town01", seed=1, duration_s=2.0), tmp_path / "r")
    (tmp_path / "r" / "truth.parquet").write_bytes(b"not parquet")
    with pytest.raises(RecordingError, match=r"truth\.parquet"):
        Recording.open(tmp_path / "r")
    (tmp_path / "r" / "vehicles.csv").unlink()
    with pytest.raises(RecordingError, match=r"vehicles\.csv"):
        Recording.open(tmp_path / "r")
    with pytest.raises(RecordingError, match="not a directory"):
        Recording.open(tmp_path / "nothing")


def test_unknown_map_is_an_error(tmp_path):
    with pytest.raises(RecordingError, match=r"nowhere\.xodr"):
        simulate(RunConfig(map="nowhere.xodr"), tmp_path / "r")
