"""Oracle sightings: exact positions without noise, sampling, the paper's noise, the CLI."""

from __future__ import annotations

import numpy as np
import pytest

from dashtraj.cli import main
from dashtraj.trajectory.io import read_sightings
from dashtraj.world.oracle import OracleConfig, OracleError, oracle_sightings
from dashtraj.world.recording import Recording, RunConfig, simulate


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    root = tmp_path_factory.mktemp("oracle")
    mp = pytest.MonkeyPatch()
    mp.setenv("DASHTRAJ_CACHE", str(root / "cache"))
    try:
        simulate(RunConfig(map="town10", seed=4, duration_s=90.0), root / "run")
    finally:
        mp.undo()
    return Recording.open(root / "run")


def _true_xy(rec, vid):
    st = rec.states
    t = st.column("t").to_numpy()
    v = st.column("vehicle_id").to_numpy()
    sel = v == vid
    return {round(a, 6): (x, y) for a, x, y in zip(
        t[sel], st.column("x").to_numpy()[sel], st.column("y").to_numpy()[sel], strict=True)}


def _seen_vehicle(rec) -> int:
    truth = rec.truth
    close = truth.column("distance_m").to_numpy() <= 15.0
    ids, counts = np.unique(truth.column("vehicle_id").to_numpy()[close], return_counts=True)
    return int(ids[np.argmax(counts)])


def test_no_noise_puts_sightings_on_the_truth(recording):
    vid = _seen_vehicle(recording)
    s = oracle_sightings(recording, OracleConfig(vehicle=vid))
    assert len(s) > 3
    truth = _true_xy(recording, vid)
    for x in s:
        tx, ty = truth[round(x.t, 6)]
        assert np.hypot(x.x - tx, x.y - ty) < 0.1
        assert x.distance <= 15.0
        # position = camera + distance along (observer yaw + signed bearing)
        a = np.radians(x.observer_yaw + x.bearing)
        assert np.isclose(x.observer_x + x.distance * np.cos(a), x.x)


def test_one_sighting_per_track_every_half_second(recording):
    s = oracle_sightings(recording, OracleConfig(vehicle=_seen_vehicle(recording)))
    by_track: dict[int, list[float]] = {}
    for x in s:
        by_track.setdefault(x.track_id, []).append(x.t)
    for times in by_track.values():
        assert np.all(np.diff(sorted(times)) >= 0.5 - 1e-9)
    cls = recording.vehicle(_seen_vehicle(recording))["vehicle_class"]
    assert {x.vehicle_class for x in s} == {cls}


def test_paper_noise_is_seeded_and_realistic(recording):
    vid = _seen_vehicle(recording)
    exact = oracle_sightings(recording, OracleConfig(vehicle=vid))
    a = oracle_sightings(recording, OracleConfig(vehicle=vid, noise="paper", seed=1))
    b = oracle_sightings(recording, OracleConfig(vehicle=vid, noise="paper", seed=1))
    c = oracle_sightings(recording, OracleConfig(vehicle=vid, noise="paper", seed=2))
    assert a == b and a != c and len(a) == len(exact)
    err = np.array([np.hypot(p.x - q.x, p.y - q.y) for p, q in zip(a, exact, strict=True)])
    assert 0.0 < np.median(err) < 6.0


def test_bad_settings(recording):
    with pytest.raises(OracleError, match="none, paper"):
        oracle_sightings(recording, OracleConfig(noise="gaussian"))


def test_cli_simulate_then_sightings(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("DASHTRAJ_CACHE", str(tmp_path / "cache"))
    run = tmp_path / "run"
    assert main(["simulate", "--town", "town10", "--observers", "4", "--agents", "10",
                 "--seed", "3", "--duration", "40", "-o", str(run), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "15 vehicles" in out and "801 frames" in out
    csv_path = tmp_path / "s.csv"
    assert main(["sightings", "--oracle", "--noise", "paper", str(run), "-o", str(csv_path),
                 "--max-distance", "60"]) == 0
    assert "sightings of vehicle target" in capsys.readouterr().out
    rows = read_sightings(csv_path)
    assert all(r.distance is not None for r in rows)
