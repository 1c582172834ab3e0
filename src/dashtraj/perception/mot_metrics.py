"""Multi-object tracking metrics: HOTA, IDF1 and MOTA, as TrackEval computes them.

Input per sequence: for every frame, the ground-truth ids and boxes and the tracker's
ids and boxes (xyxy pixels); similarity = IoU. Implemented in numpy/scipy after
TrackEval's code (Luiten et al.), so that the command runs without it, and checked in
the tests against the packages themselves (`motmetrics` for IDF1 and MOTA, TrackEval
for HOTA, where installed):

- CLEAR MOTA (Bernardin & Stiefelhagen 2008): per frame, Hungarian matching at IoU ≥ 0.5
  preferring last frame's pairs; MOTA = 1 − (FN + FP + IDSW) / #gt.
- Identity IDF1 (Ristani et al. 2016): one global bipartite matching of gt ids to
  tracker ids maximising frames matched at IoU ≥ 0.5; IDF1 = 2 IDTP / (#gt + #tracker).
- HOTA (Luiten et al. 2021): for α = 0.05 … 0.95, matching by the global alignment score
  times IoU, DetA = TP / (TP + FN + FP), AssA = mean over TPs of the matched pair's
  TPA / (TPA + FNA + FPA); HOTA_α = √(DetA AssA), HOTA = mean over α.

Sequences are combined as TrackEval does: counts summed, AssA weighted by TP.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from dashtraj.perception.detections import iou_matrix

ALPHAS = np.arange(0.05, 0.99, 0.05)
_EPS = np.finfo(float).eps


@dataclass
class Sequence:
    """Per-frame ground truth and tracker output of one video.

    ``frames``: list of (gt_ids (G,), gt_boxes (G, 4), tr_ids (T,), tr_boxes (T, 4)).
    """

    frames: list = field(default_factory=list)

    def add(self, gt_ids, gt_boxes, tr_ids, tr_boxes) -> None:
        self.frames.append((np.asarray(gt_ids, np.int64),
                            np.asarray(gt_boxes, float).reshape(-1, 4),
                            np.asarray(tr_ids, np.int64),
                            np.asarray(tr_boxes, float).reshape(-1, 4)))


def _relabel(frames):
    gt_u = np.unique(np.concatenate([f[0] for f in frames] + [np.zeros(0, np.int64)]))
    tr_u = np.unique(np.concatenate([f[2] for f in frames] + [np.zeros(0, np.int64)]))
    out = []
    for g, gb, t, tb in frames:
        out.append((np.searchsorted(gt_u, g), gb, np.searchsorted(tr_u, t), tb,
                    iou_matrix(gb, tb)))
    return out, len(gt_u), len(tr_u)


def counts(seq: Sequence) -> dict:
    """The additive counts of one sequence (CLEAR, Identity, HOTA per α)."""
    frames, n_gt, n_tr = _relabel(seq.frames)
    # ---- CLEAR
    tp = fn = fp = idsw = 0
    prev_tr = np.full(n_gt, -1)
    prev_matched = np.full(n_gt, -1)
    n_gt_dets = n_tr_dets = 0
    for g, _, t, _, sim in frames:
        n_gt_dets += len(g)
        n_tr_dets += len(t)
        if len(g) == 0 or len(t) == 0:
            fn += len(g)
            fp += len(t)
            continue
        score = sim.copy()
        score[(prev_tr[g][:, None] == t[None, :]) & (sim >= 0.5 - _EPS)] += 1000.0
        score[sim < 0.5 - _EPS] = 0
        r, c = linear_sum_assignment(-score)
        ok = score[r, c] > _EPS
        r, c = r[ok], c[ok]
        mg, mt = g[r], t[c]
        sw = (prev_matched[mg] != -1) & (prev_matched[mg] != mt)  # TrackEval's IDSW
        idsw += int(sw.sum())
        prev_tr[:] = -1
        prev_tr[mg] = mt
        prev_matched[mg] = mt
        tp += len(r)
        fn += len(g) - len(r)
        fp += len(t) - len(r)
    # ---- Identity
    pot = np.zeros((n_gt, n_tr))
    gt_cnt = np.zeros(n_gt)
    tr_cnt = np.zeros(n_tr)
    for g, _, t, _, sim in frames:
        m = sim >= 0.5 - _EPS
        rr, cc = np.nonzero(m)
        np.add.at(pot, (g[rr], t[cc]), 1)
        np.add.at(gt_cnt, g, 1)
        np.add.at(tr_cnt, t, 1)
    if n_gt and n_tr:
        # TrackEval: cost over the (gt + tr) square with false-negative/positive dummies
        fn_mat = np.zeros((n_gt + n_tr, n_gt + n_tr))
        fp_mat = np.zeros((n_gt + n_tr, n_gt + n_tr))
        fp_mat[n_gt:, :n_tr] = 1e10
        fn_mat[:n_gt, n_tr:] = 1e10
        for i in range(n_gt):
            fn_mat[i, :n_tr] = gt_cnt[i]
            fn_mat[i, n_tr + i] = gt_cnt[i]
        for j in range(n_tr):
            fp_mat[:n_gt, j] = tr_cnt[j]
            fp_mat[n_gt + j, j] = tr_cnt[j]
        fn_mat[:n_gt, :n_tr] -= pot
        fp_mat[:n_gt, :n_tr] -= pot
        r, c = linear_sum_assignment(fn_mat + fp_mat)
        idfn = fn_mat[r, c].sum().astype(int)
        idfp = fp_mat[r, c].sum().astype(int)
        idtp = int(gt_cnt.sum() - idfn)
    else:
        idtp, idfn, idfp = 0, int(gt_cnt.sum()), int(tr_cnt.sum())
    # ---- HOTA
    pot = np.zeros((n_gt, n_tr))
    for g, _, t, _, sim in frames:
        denom = sim.sum(0)[None, :] + sim.sum(1)[:, None] - sim
        s = np.where(denom > _EPS, sim / np.where(denom > _EPS, denom, 1.0), 0.0)
        pot[g[:, None], t[None, :]] += s
    ga = pot / np.maximum(gt_cnt[:, None] + tr_cnt[None, :] - pot, _EPS)
    na = len(ALPHAS)
    h_tp, h_fn, h_fp, loc = np.zeros(na), np.zeros(na), np.zeros(na), np.zeros(na)
    mc = np.zeros((na, n_gt, n_tr))
    for g, _, t, _, sim in frames:
        if len(g) == 0 or len(t) == 0:
            h_fn += len(g)
            h_fp += len(t)
            continue
        score = ga[g[:, None], t[None, :]] * sim
        r, c = linear_sum_assignment(-score)
        for a, alpha in enumerate(ALPHAS):
            ok = sim[r, c] >= alpha - _EPS
            ar, ac = r[ok], c[ok]
            h_tp[a] += len(ar)
            h_fn[a] += len(g) - len(ar)
            h_fp[a] += len(t) - len(ar)
            if len(ar):
                loc[a] += sim[ar, ac].sum()
                mc[a][g[ar], t[ac]] += 1
    ass_a = np.zeros(na)
    for a in range(na):
        m = mc[a]
        ass = m / np.maximum(1, gt_cnt[:, None] + tr_cnt[None, :] - m)
        ass_a[a] = (m * ass).sum() / max(1.0, h_tp[a])
    return {"tp": tp, "fn": fn, "fp": fp, "idsw": idsw, "num_gt": n_gt_dets,
            "num_tr": n_tr_dets, "idtp": idtp, "idfn": idfn, "idfp": idfp,
            "hota_tp": h_tp, "hota_fn": h_fn, "hota_fp": h_fp, "ass_a_tp": ass_a * h_tp,
            "loc": loc}


def summarize(all_counts: list[dict]) -> dict:
    """HOTA, DetA, AssA, IDF1, MOTA (and the counts behind them) over sequences."""
    s = {k: sum(c[k] for c in all_counts) for k in all_counts[0]} if all_counts else {}
    if not s:
        return {"hota": 0.0, "deta": 0.0, "assa": 0.0, "idf1": 0.0, "mota": 0.0}
    det_a = s["hota_tp"] / np.maximum(1.0, s["hota_tp"] + s["hota_fn"] + s["hota_fp"])
    ass_a = s["ass_a_tp"] / np.maximum(1.0, s["hota_tp"])
    hota = np.sqrt(det_a * ass_a)
    n_gt = max(1, s["num_gt"])
    return {
        "hota": float(hota.mean()), "deta": float(det_a.mean()), "assa": float(ass_a.mean()),
        "idf1": float(s["idtp"] / max(1.0, s["idtp"] + 0.5 * s["idfp"] + 0.5 * s["idfn"])),
        "mota": float(1.0 - (s["fn"] + s["fp"] + s["idsw"]) / n_gt),
        "idsw": int(s["idsw"]), "num_gt": int(s["num_gt"]), "num_tracked": int(s["num_tr"]),
        "fn": int(s["fn"]), "fp": int(s["fp"]),
    }


def evaluate(sequences: list[Sequence]) -> dict:
    """`summarize` of the `counts` of every sequence."""
    return summarize([counts(q) for q in sequences])
