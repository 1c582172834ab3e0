"""`dashtraj reconstruct` and `dashtraj bench-reconstruct` end to end through the CLI.

Skipped when ``../shared/maps/carla`` is missing.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from carla_maps import carla_map_path
from dashtraj.cli import main
from dashtraj.roads import RoadMap
from dashtraj.trajectory.io import read_trajectory, write_sightings
from dashtraj.trajectory.reconstruct import reconstruct
from dashtraj.trajectory.synth import make_trips


@pytest.fixture(scope="module")
def town01_path() -> Path:
    return carla_map_path("Town01")


@pytest.fixture(scope="module")
def trip(town01_path):
    m = RoadMap.from_file(town01_path)
    return m, make_trips(m, 1, np.random.default_rng(1))[0]


@pytest.mark.parametrize("method", ["hmm", "shortest-path"])
def test_reconstruct_round_trip(tmp_path, town01_path, trip, method, capsys):
    m, t = trip
    sightings = tmp_path / "s.csv"
    out = tmp_path / "t.csv"
    write_sightings(sightings, t.sightings)
    rc = main(["reconstruct", "--map", str(town01_path), "--sightings", str(sightings),
               "--method", method, "-o", str(out)])
    assert rc == 0
    line = capsys.readouterr().out.strip()
    traj = read_trajectory(out)
    rec = reconstruct(m, list(t.sightings), method=method)
    # The CSV holds exactly what the library computes (repr floats round-trip).
    assert traj == rec.trajectory
    used = rec.details["sightings_used"]
    assert line == (f"{method}: {used} of {len(t.sightings)} sightings used, {len(traj)} "
                    f"points, {traj.length_m:.1f} m -> {out}")


def test_reconstruct_json(tmp_path, town01_path, trip, capsys):
    _, t = trip
    sightings = tmp_path / "s.csv"
    write_sightings(sightings, t.sightings)
    out = tmp_path / "t.csv"
    assert main(["reconstruct", "--map", str(town01_path), "--sightings", str(sightings),
                 "-o", str(out), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert got["method"] == "hmm" and got["sightings"] == len(t.sightings)
    assert got["points"] == len(read_trajectory(out))


def test_unknown_method_exit_code(tmp_path, town01_path, trip, capsys):
    _, t = trip
    sightings = tmp_path / "s.csv"
    write_sightings(sightings, t.sightings)
    rc = main(["reconstruct", "--map", str(town01_path), "--sightings", str(sightings),
               "--method", "nope", "-o", str(tmp_path / "t.csv")])
    assert rc == 2
    assert "valid: hmm, shortest-path" in capsys.readouterr().err


def test_turn_cost_option(tmp_path, town01_path, trip, capsys):
    m, t = trip
    sightings, out = tmp_path / "s.csv", tmp_path / "t.csv"
    write_sightings(sightings, t.sightings)
    args = ["reconstruct", "--map", str(town01_path), "--sightings", str(sightings)]
    assert main([*args, "-o", str(out), "--turn-cost", "0"]) == 0
    by_length = reconstruct(m, list(t.sightings), turn_cost_m_per_rad=0.0)
    assert read_trajectory(out) == by_length.trajectory
    for bad, says in ((["--turn-cost", "-1"], "--turn-cost"),
                      (["--turn-cost", "2", "--method", "shortest-path"], "--method hmm only")):
        rc = main([*args, "-o", str(tmp_path / "u.csv"), *bad])
        assert rc == 2
        err = capsys.readouterr().err
        assert says in err and "Traceback" not in err
    assert not (tmp_path / "u.csv").exists()


def test_missing_map_file(tmp_path, capsys):
    rc = main(["reconstruct", "--map", str(tmp_path / "none.xodr"), "--sightings",
               str(tmp_path / "s.csv"), "-o", str(tmp_path / "t.csv")])
    assert rc == 2
    assert "none.xodr" in capsys.readouterr().err


def test_bench_reconstruct_table_and_json(town01_path, capsys):
    assert main(["bench-reconstruct", "--map", str(town01_path), "--trips", "2",
                 "--seed", "0"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[1].split()[:3] == ["method", "SSPD", "mean"]
    assert [ln.split()[0] for ln in lines[2:]] == ["shortest-path", "hmm"]
    assert main(["bench-reconstruct", "--map", str(town01_path), "--trips", "2", "--seed", "0",
                 "--methods", "hmm", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert list(res["methods"]) == ["hmm"] and res["trips"] == 2 and len(res["rows"]) == 2
