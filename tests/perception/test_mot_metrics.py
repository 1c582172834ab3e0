"""dashtraj's HOTA, IDF1 and MOTA against the reference packages on random sequences
(motmetrics for IDF1 and MOTA; TrackEval for all three where installed), and a case
small enough to count by hand."""

from __future__ import annotations

import numpy as np
import pytest

from dashtraj.perception.detections import iou_matrix
from dashtraj.perception.mot_metrics import Sequence, counts, evaluate, summarize


def _random_sequence(rng, n_frames=40, n_obj=5):
    """Boxes moving at random; the 'tracker' jitters, drops, adds false boxes and swaps
    or renews ids now and then."""
    pos = rng.uniform(0, 500, (n_obj, 2))
    vel = rng.normal(0, 6, (n_obj, 2))
    size = rng.uniform(30, 90, (n_obj, 2))
    alive = rng.integers(0, n_frames // 2, n_obj), rng.integers(n_frames // 2, n_frames, n_obj)
    ids = np.arange(n_obj) + 1
    seq = Sequence()
    next_id = 100
    for f in range(n_frames):
        on = (alive[0] <= f) & (f <= alive[1])
        p = pos + vel * f
        gb = np.column_stack([p, p + size])[on]
        gi = ids[on]
        keep = rng.random(len(gi)) > 0.15
        tb = gb[keep] + rng.normal(0, 6, (keep.sum(), 4))
        ti = gi[keep] * 10
        if rng.random() < 0.1 and len(ti) >= 2:
            ti[[0, 1]] = ti[[1, 0]]
        if rng.random() < 0.05 and len(ti):
            ids[rng.integers(n_obj)] += 1000  # a renewed track id from now on
        if rng.random() < 0.3:
            q = rng.uniform(0, 500, 2)
            tb = np.vstack([tb, np.r_[q, q + 50]])
            ti = np.r_[ti, next_id]
            next_id += 1
        seq.add(gi, gb, ti, tb)
    return seq


def test_against_motmetrics():
    mm = pytest.importorskip("motmetrics")
    rng = np.random.default_rng(3)
    for _ in range(5):
        seq = _random_sequence(rng)
        acc = mm.MOTAccumulator(auto_id=True)
        for g, gb, t, tb in seq.frames:
            d = 1.0 - iou_matrix(gb, tb)
            d[d > 0.5] = np.nan
            acc.update(g.tolist(), t.tolist(), d)
        ref = mm.metrics.create().compute(acc, metrics=["idf1", "mota"], name="s")
        ours = evaluate([seq])
        assert ours["idf1"] == pytest.approx(float(ref["idf1"].iloc[0]), abs=1e-9)
        assert ours["mota"] == pytest.approx(float(ref["mota"].iloc[0]), abs=0.02)


def test_against_trackeval():
    metrics = pytest.importorskip("trackeval.metrics")
    rng = np.random.default_rng(7)
    seqs = [_random_sequence(rng) for _ in range(4)]
    res = []
    for seq in seqs:
        gt_u = np.unique(np.concatenate([f[0] for f in seq.frames]))
        tr_u = np.unique(np.concatenate([f[2] for f in seq.frames]))
        data = {"num_timesteps": len(seq.frames), "num_gt_ids": len(gt_u),
                "num_tracker_ids": len(tr_u),
                "num_gt_dets": sum(len(f[0]) for f in seq.frames),
                "num_tracker_dets": sum(len(f[2]) for f in seq.frames),
                "gt_ids": [np.searchsorted(gt_u, f[0]) for f in seq.frames],
                "tracker_ids": [np.searchsorted(tr_u, f[2]) for f in seq.frames],
                "similarity_scores": [iou_matrix(f[1], f[3]) for f in seq.frames]}
        r = {}
        for m in (metrics.HOTA(), metrics.Identity(), metrics.CLEAR()):
            r.update(m.eval_sequence(data))
        ours = summarize([counts(seq)])
        assert ours["hota"] == pytest.approx(float(np.mean(r["HOTA"])), abs=1e-9)
        assert ours["idf1"] == pytest.approx(float(r["IDF1"]), abs=1e-9)
        assert ours["mota"] == pytest.approx(float(r["MOTA"]), abs=1e-9)
        res.append(r)
    combined = metrics.HOTA().combine_sequences(dict(enumerate(res)))
    assert evaluate(seqs)["hota"] == pytest.approx(float(np.mean(combined["HOTA"])), abs=1e-9)


def test_hand_counted_id_switch():
    """One object, 4 frames, perfect boxes; the tracker changes its id after frame 2.
    MOTA = 1 − 1 IDSW / 4; IDF1 = 2·2 / (4 + 4); HOTA: DetA = 1, AssA = 2/4 → √0.5."""
    seq = Sequence()
    box = np.array([[0.0, 0.0, 10.0, 10.0]])
    for f, tid in enumerate([5, 5, 6, 6]):
        seq.add([1], box + f, [tid], box + f)
    r = evaluate([seq])
    assert r["mota"] == pytest.approx(0.75)
    assert r["idf1"] == pytest.approx(0.5)
    assert r["hota"] == pytest.approx(np.sqrt(0.5))
