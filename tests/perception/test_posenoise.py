"""Observer pose errors (`dashtraj.perception.posenoise`): the Gauss-Markov processes have
the stated spread and correlation, are seeded per observer, reach every stage that uses
the pose, and leave the truth exact."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from dashtraj.cli import main
from dashtraj.perception.localize import CameraPose
from dashtraj.perception.posenoise import PoseNoise, PoseNoiseError, PoseNoiseProcess
from dashtraj.store import SightingsDB


def _errors(noise: PoseNoise, seed: int, observer: int, ts) -> np.ndarray:
    p = PoseNoiseProcess(noise, seed, observer)
    return np.array([p.error_at(t) for t in ts])


def test_errors_have_the_stated_spread_and_correlation():
    noise = PoseNoise(2.0, 1.0, 0.5, tau_s=10.0)
    ts = np.arange(0, 20_000, 0.5)  # 2,000 correlation times
    e = _errors(noise, 3, 1, ts)
    assert np.allclose(e.std(axis=0), [2.0, 2.0, 1.0, 0.5], rtol=0.06)
    assert np.allclose(e.mean(axis=0), 0.0, atol=0.15)
    for lag_s in (0.5, 5.0, 10.0):
        k = int(lag_s / 0.5)
        r = np.corrcoef(e[:-k, 0], e[k:, 0])[0, 1]
        assert r == pytest.approx(math.exp(-lag_s / 10.0), abs=0.04)
    # the four axes are independent
    c = np.corrcoef(e.T)
    assert np.all(np.abs(c[np.triu_indices(4, 1)]) < 0.08)


def test_errors_are_seeded_per_observer_and_a_zero_sigma_axis_stays_exact():
    noise = PoseNoise(1.0, 0.0, 0.0)
    ts = np.arange(0, 10, 0.1)
    a, b = _errors(noise, 5, 2, ts), _errors(noise, 5, 2, ts)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, _errors(noise, 5, 3, ts))
    assert not np.array_equal(a, _errors(noise, 6, 2, ts))
    assert np.all(a[:, 2:] == 0.0)
    pose = CameraPose(10.0, 20.0, 1.6, 90.0, 0.0, 0.0)
    p = PoseNoiseProcess(PoseNoise(0.0, 2.0, 0.0), 0, 1).apply(pose, 0.0)
    assert (p.x, p.y, p.z, p.ground_z) == (10.0, 20.0, 1.6, 0.0) and p.yaw_deg != 90.0
    with pytest.raises(ValueError, match="after"):
        proc = PoseNoiseProcess(noise, 0, 1)
        proc.error_at(1.0)
        proc.error_at(0.5)


@pytest.mark.parametrize("text, why", [
    ("1.5", "give XY_M,YAW_DEG"), ("1,2,3,4,5", "give XY_M,YAW_DEG"), ("a,1", "not numbers"),
    ("-1,1", "xy_m must be a finite number >= 0"), ("1,nan", "yaw_deg must be"),
    ("1,1,0,0", "tau_s must be > 0")])
def test_bad_pose_noise_is_refused(text, why):
    with pytest.raises(PoseNoiseError, match=why):
        PoseNoise.parse(text)


def test_bad_pose_noise_on_the_command_line_is_one_line(small_run, tmp_path, capsys):
    assert main(["perceive", str(small_run.path), "-o", str(tmp_path / "r.db"),
                 "--pose-noise", "1,-2"]) == 2
    err = capsys.readouterr().err
    assert "--pose-noise" in err and "yaw_deg must be a finite number >= 0" in err
    assert err.count("\n") == 1 and not (tmp_path / "r.db").exists()
    assert main(["experiments", "--sightings", "oracle", "--pose-noise", "1,1", "-o",
                 str(tmp_path / "e")]) == 2
    assert "needs --sightings detections or vision" in capsys.readouterr().err


def test_perceive_with_pose_noise_moves_the_poses_not_the_truth(small_run, small_db, tmp_path):
    from dashtraj.perception.pipeline import PerceiveConfig, perceive

    path, _ = small_db
    noisy = tmp_path / "noisy.db"
    perceive(small_run, noisy, PerceiveConfig(observers=(1, 3), pose_noise=(1.5, 1.0, 0.0, 30.0),
                                              pose_noise_seed=4))
    with SightingsDB.open(path) as a, SightingsDB.open(noisy) as b:
        pa, pb = a.poses(), b.poses()
        da, db_ = a.detections(), b.detections()
        assert b.run_info()["config"]["pose_noise"] == [1.5, 1.0, 0.0, 30.0]
        assert a.run_info()["config"]["pose_noise"] is None
    assert [(p.observer_id, p.frame) for p in pa] == [(p.observer_id, p.frame) for p in pb]
    dxy = np.array([(q.cam_x - p.cam_x, q.cam_y - p.cam_y) for p, q in zip(pa, pb, strict=True)])
    dyaw = np.array([q.cam_yaw - p.cam_yaw for p, q in zip(pa, pb, strict=True)])
    assert 0.2 < np.sqrt((dxy ** 2).mean()) < 4.0 and 0.1 < np.abs(dyaw).max() < 4.0
    assert all(p.z == q.z and p.cam_pitch == q.cam_pitch for p, q in zip(pa, pb, strict=True))
    # same boxes and truth, other positions
    assert [(d.frame, d.x0, d.truth_vehicle_id) for d in da] == [
        (d.frame, d.x0, d.truth_vehicle_id) for d in db_]
    moved = np.hypot([d.x for d in da], [d.y for d in da]) - np.hypot(
        [d.x for d in db_], [d.y for d in db_])
    assert np.abs(moved).mean() > 0.1


def test_localization_eval_with_pose_noise_is_worse_and_zero_noise_changes_nothing(
        small_run, gl_available, capsys):
    def run(*extra) -> dict:
        assert main(["localization", "eval", str(small_run.path), "--localizers", "fused",
                     "--every", "1.0", "--json", *extra]) == 0
        return json.loads(capsys.readouterr().out)

    exact, zero, gnss = run(), run("--pose-noise", "0,0"), run("--pose-noise", "2,1")
    assert exact["fused"] == zero["fused"] and exact["pose_noise"] is None
    assert gnss["pose_noise"] == [2.0, 1.0, 0.0, 30.0]
    assert gnss["fused"]["median_lt20_m"] > exact["fused"]["median_lt20_m"] + 0.5
    # the bands are of the true distance, from the exact camera
    assert [gnss["fused"][k] for k in ("n_lt20", "n_20_60")] == [
        exact["fused"][k] for k in ("n_lt20", "n_20_60")]
