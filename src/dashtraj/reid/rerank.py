"""k-reciprocal re-ranking (Zhong, Zheng, Cao and Li, CVPR 2017), numpy + scipy.sparse.

A gallery image that is among a query's k nearest neighbours *and* has the query among its
own k nearest neighbours (a k-reciprocal neighbour) is far more likely to be the same
vehicle than one that is merely near. Re-ranking encodes each image by its (expanded)
k-reciprocal neighbour set, weighted by a Gaussian of the distance, and mixes the Jaccard
distance between these sets with the original distance:

    d*(q, g) = (1 − λ) · d_J(q, g) + λ · d(q, g)

Steps, as in the authors' code (the version of torchreid's ``re_ranking``, whose inputs
and outputs this function matches; ``bench/bench_rerank.py`` checks it against that
code): the (query + gallery) distance matrix is squared and divided by each column's
maximum; R(i, k1) is the k1-reciprocal set of image i; each member c whose own
round(k1/2)-reciprocal set overlaps R(i, k1) by more than two thirds adds that set
(the expansion); V[i] weights the expanded set by exp(−d); local query expansion
averages V over the k2 nearest neighbours; d_J = 1 − s / (2 − s), where s sums the
element-wise minima of two rows of V.

Cost: the whole (N, N) distance matrix of N = queries + gallery images (float32,
4 N² bytes) and its row sort; V is sparse. Meant for evaluation sets and galleries of
thousands of images (``MAX_IMAGES``), not for a 100k-image index.
"""

from __future__ import annotations

import numpy as np

from dashtraj.errors import DashtrajError


class RerankError(DashtrajError, ValueError):
    """Inputs re-ranking cannot take (the message names them)."""


MAX_IMAGES = 30_000
"""Largest queries + gallery accepted (the dense distance matrix is 4 N² bytes: 3.6 GB)."""


def _top_k(d: np.ndarray, k: int) -> np.ndarray:
    """(N, k) indices of each row's k smallest values, ascending, ties by index."""
    n = d.shape[1]
    k = min(k, n)
    if k == n:
        return np.argsort(d, axis=1, kind="stable")
    part = np.argpartition(d, k - 1, axis=1)[:, :k]
    vals = np.take_along_axis(d, part, axis=1)
    order = np.lexsort((part, vals), axis=1)
    return np.take_along_axis(part, order, axis=1)


def _reciprocal_sets(rank: np.ndarray, k: int) -> list[np.ndarray]:
    """k-reciprocal set of every image: the j among its k + 1 nearest (itself included)
    that have it among their own k + 1 nearest; ascending rank order."""
    fwd = rank[:, : k + 1]
    back = rank[fwd, : k + 1]  # (N, k + 1, k + 1)
    ids = np.arange(len(rank))[:, None, None]
    keep = (back == ids).any(axis=2)
    return [fwd[i, keep[i]] for i in range(len(rank))]


def k_reciprocal_rerank(q_g: np.ndarray, q_q: np.ndarray, g_g: np.ndarray, k1: int = 20,
                        k2: int = 6, lambda_value: float = 0.3) -> np.ndarray:
    """Re-ranked query → gallery distances (module docstring).

    Args:
        q_g: (n_query, n_gallery) distances; q_q: (n_query, n_query); g_g: (n_gallery,
            n_gallery). Any non-negative distance (dashtraj passes squared L2 distances of
            unit embeddings, as torchreid does).
        k1: size of the k-reciprocal neighbourhood (paper: 20).
        k2: neighbours averaged by the local query expansion (paper: 6; 1 = none).
        lambda_value: weight of the original distance (paper: 0.3).

    Returns:
        (n_query, n_gallery) float32 distances; smaller is more similar.

    Raises:
        RerankError (a ValueError): shapes that do not fit together, k1 < 1, k2 < 1, λ
            outside [0, 1], or more than ``MAX_IMAGES`` images.
    """
    from scipy import sparse

    q_g, q_q, g_g = (np.asarray(a, np.float64) for a in (q_g, q_q, g_g))
    nq, ng = q_g.shape
    if q_q.shape != (nq, nq) or g_g.shape != (ng, ng):
        raise RerankError(f"distance matrices do not fit: query-gallery {q_g.shape}, "
                          f"query-query {q_q.shape}, gallery-gallery {g_g.shape}")
    if k1 < 1 or k2 < 1 or not 0.0 <= lambda_value <= 1.0:
        raise RerankError(f"re-ranking needs k1 ≥ 1, k2 ≥ 1 and 0 ≤ λ ≤ 1 (got k1={k1}, "
                          f"k2={k2}, λ={lambda_value})")
    n = nq + ng
    if n > MAX_IMAGES:
        raise RerankError(f"--rerank: {n} query and gallery images need a {n} x {n} distance "
                          f"matrix; at most {MAX_IMAGES} are accepted")
    d = np.square(np.block([[q_q, q_g], [q_g.T, g_g]])).astype(np.float32)
    d /= np.maximum(d.max(axis=0), np.finfo(np.float32).tiny)
    d = np.ascontiguousarray(d.T)  # row i: image i's distances over column maxima
    rank = _top_k(d, max(k1 + 1, k2))
    recip = _reciprocal_sets(rank, k1)
    half = int(np.around(k1 / 2.0))
    recip_half = [set(r.tolist()) for r in _reciprocal_sets(rank, half)]
    cols, vals = [], []
    for i in range(n):
        r = recip[i]
        own = set(r.tolist())
        expanded = set(own)
        for c in r.tolist():
            cand = recip_half[c]
            if len(cand & own) > 2.0 / 3.0 * len(cand):
                expanded |= cand
        idx = np.fromiter(sorted(expanded), np.int64, len(expanded))
        w = np.exp(-d[i, idx])
        cols.append(idx)
        vals.append(w / w.sum())
    indptr = np.concatenate([[0], np.cumsum([len(c) for c in cols])])
    v = sparse.csr_matrix((np.concatenate(vals), np.concatenate(cols), indptr), shape=(n, n),
                          dtype=np.float64)
    if k2 > 1:  # local query expansion: the mean of V over the k2 nearest images
        kk = min(k2, n)
        avg = sparse.csr_matrix((np.full(n * kk, 1.0 / kk), rank[:, :kk].ravel(),
                                 np.arange(0, n * kk + 1, kk)), shape=(n, n))
        v = (avg @ v).tocsr()
    vc = v.tocsc()
    jac = np.empty((nq, n), np.float64)
    for i in range(nq):  # s(i, j) = sum_k min(V[i, k], V[j, k]) over the k where V[i, k] > 0
        a, b = v.indptr[i], v.indptr[i + 1]
        ks, vi = v.indices[a:b], v.data[a:b]
        starts, ends = vc.indptr[ks], vc.indptr[ks + 1]
        lens = ends - starts
        sel = np.concatenate([np.arange(s, e) for s, e in zip(starts, ends, strict=True)]) \
            if len(ks) else np.zeros(0, np.int64)
        s = np.bincount(vc.indices[sel], np.minimum(np.repeat(vi, lens), vc.data[sel]),
                        minlength=n)
        jac[i] = 1.0 - s / (2.0 - s)
    out = jac * (1.0 - lambda_value) + d[:nq] * lambda_value
    return out[:, nq:].astype(np.float32)
