"""Gallery search (faiss and numpy) equals an exact brute force."""

from __future__ import annotations

import numpy as np
import pytest

from dashtraj.reid.evaluate import l2_normalize
from dashtraj.reid.gallery import Gallery, brute_force_search


def _data(seed=0, n=3000, nq=50, dim=64):
    rng = np.random.default_rng(seed)
    g = l2_normalize(rng.normal(size=(n, dim)))
    q = l2_normalize(rng.normal(size=(nq, dim)))
    ids = rng.permutation(10 * n)[:n].astype(np.int64)
    return g, q, ids


def _reference(g, q, ids, k, metric):
    """Full sort per query in float64 (independent of the tested code paths)."""
    g64, q64 = g.astype(np.float64), q.astype(np.float64)
    out_i, out_s = [], []
    for v in q64:
        s = g64 @ v if metric == "ip" else ((g64 - v) ** 2).sum(1)
        order = np.argsort(-s if metric == "ip" else s, kind="stable")[:k]
        out_i.append(ids[order])
        out_s.append(s[order])
    return np.array(out_s), np.array(out_i)


@pytest.mark.parametrize("metric", ["ip", "l2"])
@pytest.mark.parametrize("backend", ["faiss", "numpy"])
def test_flat_equals_brute_force(metric, backend):
    pytest.importorskip("faiss") if backend == "faiss" else None
    g, q, ids = _data()
    gal = Gallery(64, metric=metric, backend=backend)
    gal.add(g[:1000], ids[:1000])
    gal.add(g[1000:], ids[1000:])
    assert len(gal) == 3000
    s, i = gal.search(q, 10)
    rs, ri = _reference(g, q, ids, 10, metric)
    assert (i == ri).all()
    assert np.allclose(s, rs, atol=1e-5)


def test_ivf_with_all_cells_probed_is_exact_and_hnsw_recall():
    pytest.importorskip("faiss")
    g, q, ids = _data(1)
    _, ri = _reference(g, q, ids, 10, "ip")
    ivf = Gallery(64, index="ivf", nlist=16, nprobe=16)
    ivf.add(g, ids)
    assert (ivf.search(q, 10)[1] == ri).all()
    hnsw = Gallery(64, index="hnsw", ef_search=128)
    hnsw.add(g, ids)
    hi = hnsw.search(q, 10)[1]
    recall = np.mean([len(set(a) & set(b)) / 10 for a, b in zip(hi, ri, strict=True)])
    assert recall >= 0.9


@pytest.mark.parametrize("backend", ["faiss", "numpy"])
def test_fewer_vectors_than_k(backend):
    pytest.importorskip("faiss") if backend == "faiss" else None
    g, q, _ = _data(2, n=3, nq=2)
    gal = Gallery(64, metric="l2", backend=backend)
    gal.add(g, [10, 11, 12])
    s, i = gal.search(q, 5)
    assert (i[:, 3:] == -1).all() and np.isinf(s[:, 3:]).all()
    assert sorted(i[0, :3].tolist()) == [10, 11, 12]


def test_bad_input():
    gal = Gallery(8, backend="numpy")
    with pytest.raises(ValueError, match=r"\(N, 8\)"):
        gal.add(np.zeros((2, 4)))
    with pytest.raises(ValueError, match="NaN"):
        gal.add(np.full((1, 8), np.nan))
    with pytest.raises(ValueError, match="valid: flat, ivf, hnsw"):
        Gallery(8, index="lsh")


def test_brute_force_search_orders_ties_by_id():
    g = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]], np.float32)
    s, i = brute_force_search(g, np.array([[1.0, 0.0]]), 3, "ip", ids=[9, 4, 1])
    assert i.tolist() == [[4, 9, 1]] and s.tolist() == [[1.0, 1.0, 0.0]]
