"""'meet' observer placement: on the built-in towns the target is seen within 15 m by
at least two observers, an oncoming observer sees its front and a following one its
back; no overlaps at the start; 'random' stays selectable; bad names are refused."""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest

from dashtraj.world.oracle import OracleConfig, oracle_sightings
from dashtraj.world.recording import Recording, RunConfig, simulate
from dashtraj.world.traffic import TrafficConfig, TrafficError


@pytest.fixture(autouse=True)
def _town_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("DASHTRAJ_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


def _run(tmp_path, town: str, seed: int, placement: str = "meet", duration: float = 180.0):
    cfg = RunConfig(map=town, seed=seed, duration_s=duration, until_target_arrives=True,
                    traffic=TrafficConfig(observer_placement=placement))
    simulate(cfg, tmp_path / "rec")
    rec = Recording.open(tmp_path / "rec")
    return rec, oracle_sightings(rec, OracleConfig(max_distance_m=15.0))


@pytest.mark.parametrize(("town", "seed"), [("town10", 0), ("town10", 2), ("town10", 4),
                                            ("town01", 1), ("town01", 2), ("town01", 5)])
def test_meet_observers_see_the_target_front_and_back(tmp_path, town, seed):
    rec, sightings = _run(tmp_path, town, seed)
    roles = {int(k): v for k, v in rec.meta["observer_roles"].items()}
    assert sorted(roles) == rec.meta["observer_ids"]
    # 4 observers: one of each role (the 4th is parked, see TrafficSim._place_observers)
    assert {"oncoming", "following", "crossing", "parked"} == set(roles.values())
    seen: dict[int, Counter] = {}
    for s in sightings:
        assert s.distance <= 15.0
        seen.setdefault(s.observer_id, Counter())[s.orientation] += 1
    assert len(seen) >= 2, seen
    oncoming = [o for o, r in roles.items() if r == "oncoming"]
    assert any(seen.get(o, {}).get("front", 0) > 0 for o in oncoming), (roles, seen)
    (follower,) = [o for o, r in roles.items() if r == "following"]
    back = seen[follower]
    assert back["back"] > 0 and back["back"] >= 0.8 * sum(back.values()), back


def test_meet_placement_no_overlap_and_deterministic():
    from dashtraj.roads import RoadMap
    from dashtraj.world.towns import town_path
    from dashtraj.world.traffic import LaneNetwork, TrafficSim, VehicleSpec

    net = LaneNetwork(RoadMap.from_file(town_path("town10")))
    specs = ([VehicleSpec(0, "target", 4.8, 2.0, 1.5)]
             + [VehicleSpec(i, "observer", 4.8, 2.0, 1.5) for i in range(1, 5)]
             + [VehicleSpec(i, "agent", 4.8, 2.0, 1.5) for i in range(5, 25)])
    for seed in range(5):
        a = TrafficSim(net, specs, TrafficConfig(), np.random.default_rng(seed))
        b = TrafficSim(net, specs, TrafficConfig(), np.random.default_rng(seed))
        assert np.array_equal(a.lane, b.lane) and np.array_equal(a.p, b.p)
        assert a.routes == b.routes and a.meet_roles == b.meet_roles
        assert set(a.meet_roles) == {1, 2, 3, 4}
        assert (net.region[a.lane] == -1).all()
        on_lane = ~a.parked  # a parked observer stands beside its lane, not in it
        for lane in set(a.lane[on_lane].tolist()):
            ps = np.sort(a.p[on_lane & (a.lane == lane)])
            assert (np.diff(ps) > 12.0).all()  # `_spawn`'s spacing on every lane
        for i, role in a.meet_roles.items():
            if role == "following":
                assert a.routes[i][-len(a.target_lanes) + 1:] == a.target_lanes[1:]
            if role == "oncoming":  # starts on a lane of the opposite direction
                road, sec, lid = net.keys[a.lane[i]]
                assert any(net.keys[j][:2] == (road, sec) and net.keys[j][2] * lid < 0
                           for j in a.target_lanes)


def test_random_placement_still_available(tmp_path):
    rec, _ = _run(tmp_path, "town01", 3, placement="random", duration=2.0)
    assert rec.meta["observer_roles"] == {}
    assert rec.config.traffic.observer_placement == "random"
    meta = json.loads((tmp_path / "rec" / "meta.json").read_text())
    assert meta["config"]["traffic"]["observer_placement"] == "random"


def test_unknown_placement_is_refused_with_the_valid_names():
    with pytest.raises(TrafficError, match="meet, random"):
        TrafficConfig(observer_placement="nearby")


def test_cli_observer_placement(tmp_path, capsys):
    from dashtraj.cli import main

    rc = main(["simulate", "--town", "town01", "--duration", "1", "--observer-placement",
               "random", "-q", "-o", str(tmp_path / "r")])
    assert rc == 0
    meta = json.loads((tmp_path / "r" / "meta.json").read_text())
    assert meta["config"]["traffic"]["observer_placement"] == "random"
    assert RunConfig().traffic.observer_placement == "meet"
