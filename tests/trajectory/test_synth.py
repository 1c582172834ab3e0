"""Synthetic trips, observers, sightings and the bench, on the real Town01 / Town10HD.

Skipped when ``../shared/maps/carla`` is missing.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from dashtraj.trajectory.reconstruct import ReconstructionError
from dashtraj.trajectory.synth import OBSERVER_KINDS, make_trips, run_bench


@pytest.fixture(scope="module")
def trips10(town10):
    return make_trips(town10, 6, np.random.default_rng(7))


def test_same_seed_same_trips(town01):
    a = make_trips(town01, 2, np.random.default_rng(3))
    b = make_trips(town01, 2, np.random.default_rng(3))
    c = make_trips(town01, 2, np.random.default_rng(4))
    for ta, tb in zip(a, b, strict=True):
        assert ta.truth == tb.truth
        assert ta.sightings == tb.sightings
        assert (ta.detour, ta.height_factor, ta.wrong_side) == (tb.detour, tb.height_factor,
                                                                 tb.wrong_side)
    assert a[0].truth != c[0].truth


def test_truth_is_a_plausible_drive(trips10):
    for trip in trips10:
        tr = trip.truth
        assert 300.0 <= tr.length_m <= 900.0 + 5.0
        dt = np.diff(tr.t)
        assert np.allclose(dt[:-1], 0.1)  # 10 Hz (the last step may be shorter)
        speed = np.linalg.norm(np.diff(tr.points, axis=0), axis=1) / dt
        assert speed.max() < 14.0 * 1.1 + 1.0
        assert np.median(speed) > 4.0


def test_sightings_follow_the_camera_model(trips10):
    n_obs = []
    for trip in trips10:
        assert len(trip.sightings) >= 3
        kinds = {o.kind for o in trip.observers}
        assert kinds <= set(OBSERVER_KINDS)
        n_obs.append(len(trip.observers))
        ts = [s.t for s in trip.sightings]
        assert ts == sorted(ts)
        assert trip.truth.t[0] <= ts[0] and ts[-1] <= trip.truth.t[-1]
        for s in trip.sightings:
            # Eq. 9 done right: position = observer + D (cos, sin)(yaw + bearing).
            ang = math.radians(s.observer_yaw + s.bearing)
            assert s.x == pytest.approx(s.observer_x + s.distance * math.cos(ang), abs=1e-6)
            assert s.y == pytest.approx(s.observer_y + s.distance * math.sin(ang), abs=1e-6)
        # At most one sighting per observer per 0.5 s (tracker).
        for o in trip.observers:
            t = np.array([s.t for s in trip.sightings if s.observer_id == o.observer_id])
            assert np.all(np.diff(t) >= 0.5 - 1e-9)
    assert max(n_obs) <= 6


def test_distance_errors_match_the_paper(town10):
    # Non-tall targets, positions not mirrored: RMSE of the distance about 2.3 m (< 20 m).
    trips = make_trips(town10, 12, np.random.default_rng(11), wrong_side_prob=0.0, tall_prob=0.0)
    err = []
    for trip in trips:
        for s in trip.sightings:
            i = int(np.argmin(np.abs(trip.truth.t - s.t)))
            true_d = math.dist(trip.truth.points[i], (s.observer_x, s.observer_y))
            err.append(s.distance - true_d)
    rmse = float(np.sqrt(np.mean(np.square(err))))
    assert 1.2 < rmse < 3.0
    assert len(err) > 50


def test_orientation_labels_come_from_the_true_pose(town10):
    trips = make_trips(town10, 8, np.random.default_rng(5))
    labels = [s.orientation for t in trips for s in t.sightings]
    assert "back" in labels and "front" in labels


def test_run_bench_small(town01):
    res = run_bench(town01, 3, seed=2)
    assert res["trips"] == 3 and set(res["methods"]) == {"shortest-path", "hmm"}
    assert len(res["rows"]) == 6
    for m in res["methods"].values():
        assert 0 <= m["sspd_mean_m"] <= m["hausdorff_mean_m"]
    assert res["methods"]["hmm"]["sspd_mean_m"] < res["methods"]["shortest-path"]["sspd_mean_m"]


def test_run_bench_unknown_method(town01):
    with pytest.raises(ReconstructionError, match="valid: hmm, shortest-path"):
        run_bench(town01, 1, seed=0, methods=("hmm", "viterbi2"))
