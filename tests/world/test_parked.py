"""Parked observers: they never move, stand on the road edge beside their lane (not in
a driving lane), nobody drives into them or queues behind them, and in "meet"
placement they see the target; "random" placement parks a share of the observers."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dashtraj.roads import RoadMap
from dashtraj.world.oracle import OracleConfig, oracle_sightings
from dashtraj.world.recording import Recording, RunConfig, simulate
from dashtraj.world.towns import town_path
from dashtraj.world.traffic import LaneNetwork, TrafficConfig, TrafficError, TrafficSim
from traffic_helpers import obb_overlap
from traffic_helpers import traffic_vehicles as _vehicles


@pytest.fixture(autouse=True)
def _town_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("DASHTRAJ_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


@pytest.fixture(scope="module")
def nets(tmp_path_factory):
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("DASHTRAJ_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))
        return {t: LaneNetwork(RoadMap.from_file(town_path(t))) for t in ("town10", "town01")}


@pytest.mark.parametrize(("town", "seed", "placement"),
                         [("town10", 3, "meet"), ("town01", 4, "meet"),
                          ("town10", 1, "random"), ("town01", 2, "random")])
def test_parked_stands_on_the_edge_and_blocks_nobody(nets, town, seed, placement):
    net = nets[town]
    rng = np.random.default_rng(seed)
    cfg = TrafficConfig(observer_placement=placement, parked_fraction=0.5)
    sim = TrafficSim(net, _vehicles(rng), cfg, rng)
    parked = np.flatnonzero(sim.parked)
    assert len(parked) >= 1
    if placement == "meet":
        assert {sim.meet_roles[int(i)] for i in parked} == {"parked"}
    frames = [sim.frame()]
    step = sim.cfg.step_s
    for k in range(round(120.0 / step)):
        sim.step()
        if k % 5 == 4:
            frames.append(sim.frame())
    moving = ~sim.parked
    for f in frames:
        for key in ("x", "y", "z", "yaw", "road_id", "section_id", "lane_id", "s"):
            assert np.array_equal(f[key][parked], frames[0][key][parked]), key
        assert (f["speed"][parked] == 0.0).all()
        ov = obb_overlap(f["x"], f["y"], f["yaw"], sim.length, sim.width)
        assert not ov[np.ix_(parked, moving)].any()
    # on the edge: beyond the half width of the lane it stands beside, within 3 m of it
    f0 = frames[0]
    m = net.map
    for i in parked:
        key = (int(f0["road_id"][i]), int(f0["section_id"][i]), int(f0["lane_id"][i]))
        cx, cy, _cz, _cyaw = m._lane_pose(key, np.array([f0["s"][i]]))
        d = float(np.hypot(f0["x"][i] - cx[0], f0["y"][i] - cy[0]))
        w = float(net.width(np.array([sim.lane[i]]), np.array([sim.p[i]]))[0])
        assert 0.5 * w < d <= 0.5 * w + 3.0, (d, w)
        assert net.region[sim.lane[i]] == -1
    # nobody is held up behind a parked car (same bound as the deadlock test)
    speed = np.stack([f["speed"] for f in frames])[:, moving]
    still = np.zeros(speed.shape[1])
    longest = 0.0
    for v in speed:
        still = np.where(v < 0.1, still + 5 * step, 0.0)
        longest = max(longest, still.max())
    assert longest < 90.0


@pytest.mark.parametrize("town", ["town10", "town01"])
def test_meet_parked_sees_the_target(tmp_path, town):
    saw = 0
    for seed in range(3):
        cfg = RunConfig(map=town, seed=seed, duration_s=180.0, until_target_arrives=True)
        simulate(cfg, tmp_path / str(seed))
        rec = Recording.open(tmp_path / str(seed))
        roles = {int(k): v for k, v in rec.meta["observer_roles"].items()}
        parked = [o for o, r in roles.items() if r == "parked"]
        assert parked == rec.meta["parked_observer_ids"]
        vid = rec.states.column("vehicle_id").to_numpy()
        cols = {c: rec.states.column(c).to_numpy() for c in ("speed", "x", "y", "yaw")}
        for o in parked:
            mine = vid == o
            assert mine.any()
            assert (cols["speed"][mine] == 0.0).all()
            for c in ("x", "y", "yaw"):
                assert np.unique(cols[c][mine]).size == 1
        sightings = oracle_sightings(rec, OracleConfig(max_distance_m=15.0))
        if any(s.observer_id in parked and s.distance <= 15.0 for s in sightings):
            saw += 1
    assert saw >= 2


def test_random_placement_parks_a_share(tmp_path):
    cfg = RunConfig(map="town01", seed=3, duration_s=2.0,
                    traffic=TrafficConfig(observer_placement="random"))
    simulate(cfg, tmp_path / "rec")
    meta = json.loads((tmp_path / "rec" / "meta.json").read_text())
    assert meta["parked_observer_ids"] == [4]  # the last of 4 observers (0.25 * 4)
    assert meta["observer_roles"] == {}
    cfg0 = RunConfig(map="town01", seed=3, duration_s=2.0,
                     traffic=TrafficConfig(observer_placement="random", parked_fraction=0.0))
    simulate(cfg0, tmp_path / "rec0")
    assert json.loads((tmp_path / "rec0" / "meta.json").read_text())["parked_observer_ids"] == []


def test_meet_without_parked_role_when_fraction_is_zero(nets):
    rng = np.random.default_rng(0)
    sim = TrafficSim(nets["town10"], _vehicles(rng), TrafficConfig(parked_fraction=0.0), rng)
    assert "parked" not in sim.meet_roles.values() and not sim.parked.any()


def test_parked_fraction_checked_and_old_configs_mean_none():
    with pytest.raises(TrafficError, match="parked_fraction"):
        TrafficConfig(parked_fraction=1.5)
    d = TrafficConfig().to_dict()
    del d["parked_fraction"]
    assert TrafficConfig.from_dict(d).parked_fraction == 0.0
    assert TrafficConfig.from_dict(TrafficConfig().to_dict()) == TrafficConfig()


def test_cli_parked_fraction(tmp_path):
    from dashtraj.cli import main

    rc = main(["simulate", "--town", "town01", "--duration", "1", "--observer-placement",
               "random", "--parked-fraction", "0.5", "-q", "-o", str(tmp_path / "r")])
    assert rc == 0
    meta = json.loads((tmp_path / "r" / "meta.json").read_text())
    assert meta["config"]["traffic"]["parked_fraction"] == 0.5
    assert meta["parked_observer_ids"] == [3, 4]
    assert main(["simulate", "--parked-fraction", "2", "-o", str(tmp_path / "x")]) == 2
