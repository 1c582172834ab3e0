"""The camera's pitch self-calibrated from the vehicles in view (`dashtraj.perception.selfcal`)."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from dashtraj.cli import main
from dashtraj.perception.detections import DETECTION_CLASSES
from dashtraj.perception.localize import CameraPose, _model_extent
from dashtraj.perception.selfcal import PitchCalibrator, SelfCalibrationError
from dashtraj.world.camera import CameraSpec

SPEC = CameraSpec()
CAR_FRONT, CAR_BACK = DETECTION_CLASSES.index("car_front"), DETECTION_CLASSES.index("car_back")
TRUCK_BACK = DETECTION_CLASSES.index("truck_back")
TRUE = CameraPose(0.0, 0.0, 1.6, 0.0, 0.0, 0.0)  # the camera as it really is


def _box(x, y, yaw, vc):
    """The pixel box (whole pixels, as a renderer's) of a class-typical vehicle at (x, y)."""
    umin, umax, vbot, vtop = _model_extent(SPEC, TRUE, np.array([x]), np.array([y]),
                                           np.array([0.0]), np.array([yaw]), vc)
    return [math.floor(umin[0]), math.floor(vtop[0]), math.ceil(umax[0]), math.ceil(vbot[0])]


def _scene(t):
    """One frame at time t (s): an oncoming car 70 → 14 m away in the next lane, a truck
    driving away 16 → 60 m ahead, a car following at a constant 25 m."""
    return ([_box(70.0 - 8.0 * t, -3.5, 180.0, 0), _box(16.0 + 6.3 * t, 0.0, 0.0, 1),
             _box(25.0, 3.5, 0.0, 0)], [CAR_FRONT, TRUCK_BACK, CAR_BACK])


def _run(cal, pitch_error_deg, times):
    """Feed the frames seen from a pose whose pitch is off by ``pitch_error_deg``; the
    corrected poses."""
    pose = replace(TRUE, pitch_deg=pitch_error_deg)
    out = []
    for t in times:
        boxes, cls = _scene(t)
        out.append(cal.correct(boxes, cls, SPEC, pose, t))
    return out


TIMES = np.round(np.arange(0.0, 7.0, 0.1), 3)


@pytest.mark.parametrize("error", [-0.8, 0.5, 1.5])
def test_a_pitch_error_is_found_from_vehicles_coming_and_going(error):
    cal = PitchCalibrator()
    poses = _run(cal, error, TIMES)
    # the true pitch is the pose's plus the estimate: the corrected poses' pitch is ~0
    assert abs(poses[-1].pitch_deg) < 0.05
    assert abs(cal.estimate(TIMES[-1]) + error) < 0.05
    assert poses[0].pitch_deg == error  # one frame is no evidence: no correction yet
    # offline, the first frames get the pitch found later
    assert np.abs(cal.offsets(TIMES) + error).max() < 0.05


def test_exact_poses_are_left_as_they_are():
    cal = PitchCalibrator()
    poses = _run(cal, 0.0, TIMES)
    assert max(abs(p.pitch_deg) for p in poses) < 0.03


def test_vehicles_at_one_distance_say_nothing():
    """A car followed at a constant distance fits any horizon: no correction."""
    cal = PitchCalibrator()
    pose = replace(TRUE, pitch_deg=1.0)
    for t in TIMES:
        assert cal.correct([_box(25.0, 3.5, 0.0, 0)], [CAR_BACK], SPEC, pose, t) == pose
    assert cal.estimate(TIMES[-1]) is None
    assert np.all(cal.offsets(TIMES) == 0.0)


def test_the_estimate_holds_when_the_vehicles_are_gone():
    cal = PitchCalibrator(tau_s=5.0)
    _run(cal, 0.7, TIMES)
    pose = replace(TRUE, pitch_deg=0.7)
    later = [cal.correct([], [], SPEC, pose, 7.0 + t) for t in range(1, 60)]
    assert cal.estimate(66.0) is None  # the evidence faded
    assert abs(later[-1].pitch_deg) < 0.05  # the last estimate holds


@pytest.mark.parametrize("kw", [{"tau_s": 0}, {"min_total": float("nan")},
                                {"max_offset_deg": -1}, {"link_iou": float("inf")}])
def test_bad_settings_are_refused(kw):
    with pytest.raises(SelfCalibrationError, match=next(iter(kw))):
        PitchCalibrator(**kw)


def test_frames_out_of_order_are_refused():
    cal = PitchCalibrator()
    cal.observe(*_scene(1.0), SPEC, TRUE, 1.0)
    with pytest.raises(SelfCalibrationError, match="time order"):
        cal.observe(*_scene(0.5), SPEC, TRUE, 0.5)


@pytest.fixture(scope="module")
def busy_run(tmp_path_factory):
    """20 s on town10, seed 4, 2 observers among 30 agents, a 640 x 360 camera: observer 1
    sees vehicles come and go."""
    from dashtraj.world.recording import Recording, RunConfig, simulate

    root = tmp_path_factory.mktemp("selfcal") / "run"
    simulate(RunConfig(map="town10", seed=4, duration_s=20.0, n_observers=2, n_agents=30,
                       camera=CameraSpec(width_px=640, height_px=360)), root)
    return Recording.open(root)


def test_localization_eval_calibrates_a_mounted_pitch_error(busy_run, gl_available, capsys):
    """A camera mounted 1.5° off (a constant error: τ = 10⁶ s; `--pose-noise-seed 0`
    draws it per observer): the offline estimator's far positions come back near the exact
    poses' (measured: 15.0 m raw, 4.0 m calibrated, 2.4 m exact)."""
    def run(*extra) -> dict:
        assert main(["localization", "eval", str(busy_run.path), "--localizers", "smoothed",
                     "--every", "0.5", "--json", *extra]) == 0
        return json.loads(capsys.readouterr().out)

    off = "0,0,1.5,1000000"
    raw, cal = run("--pose-noise", off), run("--pose-noise", off, "--calibrate-pitch")
    assert cal["calibrate_pitch"] and not raw["calibrate_pitch"]
    assert raw["smoothed"]["rmse_20_60_m"] > 10.0
    assert cal["smoothed"]["rmse_20_60_m"] < 6.0


def test_perceive_with_a_calibrated_pitch_places_far_vehicles_as_the_exact_pose_does(
        busy_run, gl_available, tmp_path):
    """Observer 1 perceived from a pose 1.5° off in pitch, calibrated, against the exact
    pose: the far positions agree (measured: 0.04 m median; 8.4 m for observer 2, which
    sees too few vehicles come and go to be calibrated), the stored poses carry the
    corrected pitch, the run records the setting."""
    import sqlite3

    def perceive(name, *extra):
        out = tmp_path / name
        assert main(["perceive", str(busy_run.path), "-o", str(out), "--observers", "1",
                     "-q", *extra]) == 0
        with sqlite3.connect(out) as c:
            det = np.array(c.execute("SELECT frame, idx, x, y, distance_m FROM detections "
                                     "ORDER BY frame, idx").fetchall())
            pitch = np.array(c.execute("SELECT cam_pitch FROM poses ORDER BY frame").fetchall())
            config = json.loads(c.execute("SELECT config FROM run").fetchone()[0])
        return det, pitch[:, 0], config

    exact, p_exact, c_exact = perceive("exact.db")
    cal, p_cal, c_cal = perceive("cal.db", "--pose-noise", "0,0,1.5,1000000",
                                 "--calibrate-pitch")
    assert c_cal["calibrate_pitch"] and not c_exact["calibrate_pitch"]
    assert (exact[:, :2] == cal[:, :2]).all()
    far = exact[:, 4] > 20.0
    assert far.sum() > 100
    assert np.median(np.hypot(*(exact[far, 2:4] - cal[far, 2:4]).T)) < 0.5
    assert abs(p_cal[-1] - p_exact[-1]) < 0.1 and abs(p_cal[0] - p_exact[0]) > 0.5
