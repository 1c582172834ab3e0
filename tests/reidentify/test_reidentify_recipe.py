"""The decision recipe: query expansion, the crop filter, the far rule, and their record in
the calibration (the run must decide as the threshold was calibrated)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dashtraj.reidentify.decision import (
    EXPANDED_RECIPE,
    PAPER_RECIPE,
    Calibration,
    Recipe,
    ReidDecisionError,
    adequate_crops,
    calibrate_threshold,
    pair_distances,
    threshold_from_pairs,
)
from dashtraj.reidentify.select import select_target_tracks


def noisy_set(seed: int = 3, ids: int = 4, cams: int = 3, per: int = 4, dim: int = 16,
              noise: float = 0.8):
    """Unit embeddings of `ids` identities by `cams` cameras, `per` each: identity
    direction plus Gaussian noise (`noise` times a unit normal per axis)."""
    rng = np.random.default_rng(seed)
    centres = rng.normal(size=(ids, dim))
    e, id_, cam = [], [], []
    for a in range(ids):
        for c in range(cams):
            for _ in range(per):
                v = centres[a] + noise * rng.normal(size=dim)
                e.append(v / np.linalg.norm(v))
                id_.append(a)
                cam.append(c)
    return np.array(e), id_, cam


def brute_force_track_pairs(e, ids, cams, agg):
    """Independent: every (query track, gallery track of another camera) pair by loops."""
    groups: dict = {}
    for i, k in enumerate(zip(ids, cams, strict=True)):
        groups.setdefault(k, []).append(i)
    pos, neg = [], []
    for (qa, qc), qm in groups.items():
        q = e[qm].mean(axis=0)
        q = q / np.linalg.norm(q)
        for (ga, gc), gm in groups.items():
            if gc == qc:
                continue
            d = agg([1.0 - float(q @ e[m]) for m in gm])
            (pos if ga == qa else neg).append(d)
    return np.sort(pos), np.sort(neg)


def test_track_queries_match_a_brute_force_count():
    e, ids, cams = noisy_set()
    for name, agg in (("median", np.median), ("mean", np.mean), ("min", np.min)):
        pos, neg = pair_distances(e, ids, cams, name, max_queries=None, query="track")
        want_pos, want_neg = brute_force_track_pairs(e, ids, cams, agg)
        assert len(pos) == 4 * 3 * 2 and len(neg) == 4 * 3 * 3 * 2
        assert np.sort(pos) == pytest.approx(want_pos, abs=1e-9)
        assert np.sort(neg) == pytest.approx(want_neg, abs=1e-9)
    with pytest.raises(ReidDecisionError, match="unknown query 'mean'; valid: crop, track"):
        pair_distances(e, ids, cams, query="mean")


def test_query_expansion_separates_better_than_one_crop():
    # averaging a track's crops cancels their noise: the positives move down, so at the
    # same false-accept rate more of them pass (measured: recall 0.34 -> 0.81 at FAR 0.05)
    e, ids, cams = noisy_set(seed=5, ids=6, per=6, dim=24, noise=2.0)
    rates = {}
    for query in ("crop", "track"):
        pos, neg = pair_distances(e, ids, cams, "median", max_queries=None, query=query)
        cal = threshold_from_pairs(pos, neg, "far", max_far=0.05)
        rates[query] = cal.recall
    assert rates["track"] > 2 * rates["crop"]


def test_far_rule_bounds_the_false_accepts():
    pos = np.array([0.1, 0.2, 0.3, 0.6])
    neg = np.array([0.25, 0.5, 0.7, 0.8, 0.9, 1.0, 1.0, 1.0, 1.0, 1.0])
    c = threshold_from_pairs(pos, neg, "far", max_far=0.1)
    # one negative of ten (0.25) may pass: the last candidate before the second (0.5) is
    # the midpoint of 0.3 and 0.5
    assert c.threshold == pytest.approx(0.4) and c.false_accept_rate == 0.1
    assert c.recall == 0.75 and c.rule == "far" and c.max_far == 0.1
    zero = threshold_from_pairs(pos, neg, "far", max_far=0.0)
    assert zero.false_accept_rate == 0.0 and zero.recall == 0.5  # 0.1 and 0.2 below 0.25
    with pytest.raises(ReidDecisionError, match=r"max false-accept rate must be in \[0, 1\]"):
        threshold_from_pairs(pos, neg, "far", max_far=1.5)


def test_adequate_crops_size_and_border():
    boxes = np.array([[10, 10, 60, 33],      # 23 px tall: too small
                      [10, 10, 60, 34],      # 24 px: kept
                      [0, 10, 60, 60],       # touches the left border
                      [600, 300, 640, 359],  # touches the right border
                      [100, 100, 300, 357]])  # 3 px from the bottom: kept
    assert adequate_crops(boxes, 640, 360, EXPANDED_RECIPE).tolist() == [
        False, True, False, False, True]
    assert adequate_crops(boxes, 640, 360, PAPER_RECIPE).all()
    assert adequate_crops(np.zeros((0, 4)), 640, 360, EXPANDED_RECIPE).shape == (0,)
    with pytest.raises(ReidDecisionError, match="unknown query 'all'"):
        Recipe(query="all")
    with pytest.raises(ReidDecisionError, match="border_px must be >= 0 or None"):
        Recipe(border_px=-1.0)


def test_calibration_records_its_recipe_and_old_files_read_as_the_paper():
    e, ids, cams = noisy_set()
    cal = calibrate_threshold(e, ids, cams, rule="far", max_far=0.05, max_queries=None,
                              recipe=EXPANDED_RECIPE)
    assert cal.recipe == EXPANDED_RECIPE and cal.max_far == 0.05
    back = Calibration(**json.loads(json.dumps(cal.to_dict())))
    assert back == cal
    old = {k: v for k, v in cal.to_dict().items()
           if k not in ("query", "min_box_px", "border_px", "max_far")}
    assert Calibration(**old).recipe == Recipe(cal.aggregate, "crop", 0.0, None)


def test_the_anchor_is_a_candidate_whatever_its_distance(town01):
    from dashtraj.trajectory.records import Sighting

    def track(obs, tid, t0, x, y):
        return [Sighting(t=t0 + i, observer_id=obs, observer_x=x, observer_y=y,
                         observer_yaw=0.0, x=x, y=y, orientation="back", vehicle_class="car",
                         track_id=tid) for i in range(2)]

    wp = town01.generate_waypoints(50.0)[0]
    loc = wp.transform.location
    tracks = {(1, 1): track(1, 1, 0.0, loc.x, loc.y)}
    d, keys = np.array([0.9, 0.8]), [(1, 1), (1, 1)]
    plain = select_target_tracks(town01, d, keys, tracks, 0.5, anchor=(1, 1), gate=None)
    assert plain.candidates == ()
    kept = select_target_tracks(town01, d, keys, tracks, 0.5, anchor=(1, 1), gate=None,
                                keep_anchor=True)
    assert kept.candidates == ((1, 1),) and kept.accepted == ((1, 1),)
