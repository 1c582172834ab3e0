"""Track decisions and threshold calibration on embeddings whose distances are known exactly.

Synthetic set: identity a's direction is the basis vector e_a; embedding i of it is
cos(θ_i) e_a + sin(θ_i) e_(K + i) with its own noise axis, so the cosine distance of
two embeddings is exactly 1 − cos θ_i cos θ_j for the same identity and exactly 1
for different identities.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from dashtraj.reidentify.decision import (
    AGGREGATORS,
    ReidDecisionError,
    calibrate_threshold,
    cosine_distances,
    decide_tracks,
    pair_distances,
    threshold_from_pairs,
)

K_IDS, K_CAMS, PER = 5, 3, 3


def synthetic_set(dim: int = 512):
    n = K_IDS * K_CAMS * PER
    rng = np.random.default_rng(4)
    theta = rng.uniform(0.2, 1.2, size=n)  # radians
    e = np.zeros((n, dim))
    ids, cams = [], []
    for i in range(n):
        a, c = i // (K_CAMS * PER), (i // PER) % K_CAMS
        e[i, a] = math.cos(theta[i])
        e[i, K_IDS + i] = math.sin(theta[i])
        ids.append(a)
        cams.append(c)
    return e, ids, cams, np.cos(theta)


def test_cosine_distances_exact_and_checked():
    e, ids, _, c = synthetic_set()
    d = cosine_distances(e[0], e)
    assert d[0] == pytest.approx(0.0, abs=1e-12)
    assert d[1] == pytest.approx(1 - c[0] * c[1], abs=1e-12)
    assert np.all(d[np.array(ids) != ids[0]] == 1.0)
    assert cosine_distances(e[:2], e).shape == (2, len(e))
    with pytest.raises(ReidDecisionError, match=r"gallery row 0 has norm 2\.0000"):
        cosine_distances(e[0], 2 * e)
    with pytest.raises(ReidDecisionError, match="must be"):
        cosine_distances(e[0, :10], e)


def test_aggregators_per_track():
    d = np.array([0.1, 0.9, 0.2, 0.8, 0.3, 0.05])
    keys = ["a", "b", "a", "b", "a", "c"]
    want = {"min": (0.1, 0.8, 0.05), "mean": (0.2, 0.85, 0.05),
            "median": (0.2, 0.85, 0.05), "kmin-mean": (0.15, 0.8, 0.05)}
    assert set(want) == set(AGGREGATORS)
    for name, (a, b, c) in want.items():
        out = decide_tracks(d, keys, 0.5, name)
        assert [o.key for o in out] == ["a", "b", "c"]
        assert [o.detections for o in out] == [3, 2, 1]
        assert [o.distance for o in out] == pytest.approx([a, b, c])
        assert [o.target for o in out] == [True, False, True]


def test_one_lucky_crop_fools_min_not_median():
    # a look-alike's long track with one crop that happens to look like the target
    d = np.array([0.9, 0.9, 0.9, 0.3, 0.9])
    keys = [(2, 11)] * 5
    assert decide_tracks(d, keys, 0.5, "min")[0].target
    assert not decide_tracks(d, keys, 0.5, "median")[0].target
    # a true track with two truncated crops: the mean misses it, the median does not
    d = np.array([0.2, 0.25, 0.3, 1.2, 1.3])
    assert not decide_tracks(d, keys, 0.5, "mean")[0].target
    assert decide_tracks(d, keys, 0.5, "median")[0].target


def test_decide_bad_input():
    with pytest.raises(ReidDecisionError, match="unknown aggregator 'max'; valid: min, mean"):
        decide_tracks(np.array([0.1]), ["a"], 0.5, "max")
    with pytest.raises(ReidDecisionError, match="distance 1 is not finite"):
        decide_tracks(np.array([0.1, np.nan]), ["a", "a"], 0.5)
    with pytest.raises(ReidDecisionError, match="for 1 keys"):
        decide_tracks(np.array([0.1, 0.2]), ["a"], 0.5)


def test_threshold_rules_on_overlapping_pairs():
    pos = np.array([0.1, 0.2, 0.3, 0.6])
    neg = np.array([0.5, 0.7, 0.8, 0.9])
    eer = threshold_from_pairs(pos, neg, "eer")
    # at 0.55 one of four positives is rejected and one of four negatives accepted
    assert eer.threshold == pytest.approx(0.55)
    assert (eer.precision, eer.recall, eer.false_accept_rate) == (0.75, 0.75, 0.25)
    assert (eer.positives, eer.negatives) == (4, 4)
    p = threshold_from_pairs(pos, neg, "precision", target_precision=0.99)
    assert p.threshold == pytest.approx(0.4)  # the middle of the gap 0.3 .. 0.5
    assert (p.precision, p.recall, p.false_accept_rate) == (1.0, 0.75, 0.0)
    assert p.target_precision == 0.99
    p7 = threshold_from_pairs(pos, neg, "precision", target_precision=0.7)
    assert p7.threshold == pytest.approx(0.65) and p7.recall == 1.0 and p7.precision == 0.8
    # no threshold accepts anything without a false match: recall 0, said so
    none = threshold_from_pairs(np.array([0.5]), np.array([0.1]), "precision")
    assert none.recall == 0.0 and none.threshold < 0.1
    with pytest.raises(ReidDecisionError, match="unknown threshold rule 'f1'; valid: eer"):
        threshold_from_pairs(pos, neg, "f1")
    with pytest.raises(ReidDecisionError, match="no positive pairs"):
        threshold_from_pairs(np.array([]), neg)


def test_pair_distances_exact():
    e, ids, cams, c = synthetic_set()
    pos, neg = pair_distances(e, ids, cams, "median", max_queries=None)
    n = len(e)
    # independent count and values: per query, one track per (identity, other camera)
    assert len(pos) == n * (K_CAMS - 1)
    assert len(neg) == n * (K_IDS - 1) * (K_CAMS - 1)
    assert np.all(neg == 1.0)
    want = []
    for q in range(n):
        for cam in range(K_CAMS):
            if cam != cams[q]:
                members = [i for i in range(n) if ids[i] == ids[q] and cams[i] == cam]
                want.append(float(np.median([1 - c[q] * c[m] for m in members])))
    assert np.sort(pos) == pytest.approx(np.sort(want), abs=1e-12)


def test_calibration_on_separable_training_identities():
    e, ids, cams, _ = synthetic_set()
    pos, _ = pair_distances(e, ids, cams, "median", max_queries=None)
    for rule in ("eer", "precision"):
        cal = calibrate_threshold(e, ids, cams, rule=rule, max_queries=None)
        # perfectly separable: halfway between the worst positive and the negatives (1.0)
        assert cal.threshold == pytest.approx((pos.max() + 1.0) / 2, abs=1e-12)
        assert (cal.precision, cal.recall, cal.false_accept_rate) == (1.0, 1.0, 0.0)
        assert cal.aggregate == "median" and cal.rule == rule
    # a sampled calibration is deterministic for a seed and needs a generator
    a = calibrate_threshold(e, ids, cams, max_queries=10, rng=np.random.default_rng(1))
    b = calibrate_threshold(e, ids, cams, max_queries=10, rng=np.random.default_rng(1))
    assert a == b and a.positives == 10 * (K_CAMS - 1)
    with pytest.raises(ReidDecisionError, match="random generator"):
        calibrate_threshold(e, ids, cams, max_queries=10)


def test_appearance_splits_at_identity_switches():
    """Crop distances to the query of real tracks of the town10 seed 0 run from pixels
    (observer 3; threshold 0.396): track 42 swapped to another car for its last 7 crops
    in range, track 30 of observer 2 held another car for 4 crops before the target,
    track 8 is the target throughout (one crop at 0.43)."""
    from dashtraj.reidentify.decision import appearance_splits

    thr = 0.396
    t42 = [0.17, 0.19, 0.14, 0.2, 0.27, 0.32, 0.2, 0.21, 0.23, 0.21, 0.19, 0.18, 0.17, 0.17,
           0.18, 0.16, 0.19, 0.22, 0.29, 0.24, 0.18, 0.18, 0.12, 0.24, 0.16, 0.23, 0.18, 0.16,
           0.22, 0.24, 0.18, 0.67, 0.62, 0.67, 0.66, 0.68, 0.67, 0.66]
    t30 = [0.62, 0.58, 0.61, 0.62, 0.2, 0.15, 0.13, 0.12, 0.15]
    t8 = [0.21, 0.22, 0.18, 0.21, 0.2, 0.16, 0.16, 0.2, 0.12, 0.18, 0.24, 0.25, 0.22, 0.26,
          0.19, 0.21, 0.23, 0.24, 0.25, 0.26, 0.23, 0.19, 0.28, 0.33, 0.27, 0.33, 0.24, 0.27,
          0.26, 0.28, 0.25, 0.26, 0.31, 0.43, 0.31, 0.25, 0.25, 0.22, 0.23, 0.22, 0.16, 0.12]
    assert appearance_splits(np.array(t42), thr) == [31]
    assert appearance_splits(np.array(t30), thr) == [4]
    assert appearance_splits(np.array(t8), thr) == []
    # two switches: target, another car, the target again
    assert appearance_splits(np.array(t30[:4] + t30[4:] + t30[:4]), thr) == [4, 9]
    # two crops of another look are too few to cut (a bad angle), three are enough
    assert appearance_splits(np.array([0.2] * 6 + [0.7] * 2), thr) == []
    assert appearance_splits(np.array([0.2] * 6 + [0.7] * 3), thr) == [6]
    assert appearance_splits(np.array([0.2] * 6 + [0.7] * 2), thr, min_crops=2) == [6]
    # both sides on one side of the threshold: one vehicle whose look varies
    assert appearance_splits(np.array([0.1] * 5 + [0.35] * 5), thr) == []
    assert appearance_splits(np.array([0.5] * 5 + [0.9] * 5), thr) == []
    # just above the threshold: a harder angle of the target more often than another car
    near = np.array([0.43, 0.42, 0.44, 0.2, 0.21, 0.19, 0.2])
    assert appearance_splits(near, thr) == [3]
    assert appearance_splits(near, thr, margin=0.1) == []
    assert appearance_splits(np.array([]), thr) == [] and appearance_splits(np.ones(3), thr) == []
    with pytest.raises(ReidDecisionError, match="appearance_splits"):
        appearance_splits(np.array(t30), float("nan"))
    with pytest.raises(ReidDecisionError, match="appearance_splits"):
        appearance_splits(np.array(t30), thr, min_crops=0)
