"""A gallery of embeddings searched by nearest neighbour (faiss, or numpy brute force).

``Gallery(dim, metric, index)`` holds (N, dim) float32 vectors with int64 ids (e.g.
crop or track ids of a sightings database). ``search(queries, k)`` returns, per query,
the k nearest ids and their scores:

- ``metric="ip"``: inner product, larger is closer (cosine similarity for the
  L2-normalised embeddings of ``dashtraj.reid.embed``);
- ``metric="l2"``: squared Euclidean distance, smaller is closer.

Index kinds: ``"flat"`` is exact (faiss ``IndexFlatIP`` / ``IndexFlatL2``); ``"ivf"``
(inverted lists, ``nlist`` cells, ``nprobe`` searched; needs ``train``ing, done on the
first ``add``) and ``"hnsw"`` (graph, ``M`` links, ``ef_search``) are approximate, for
galleries past a million vectors. ``backend="numpy"`` is an exact brute force without
faiss (same results as ``flat``). Ties are broken by the smaller id.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

METRICS = ("ip", "l2")
INDEXES = ("flat", "ivf", "hnsw")


class Gallery:
    """Nearest-neighbour search over embeddings (module docstring).

    Args:
        dim: vector size (512 for the ReID embeddings).
        metric: "ip" or "l2". index: "flat", "ivf" or "hnsw".
        backend: "faiss" or "numpy" (flat only). nlist, nprobe: IVF cells and cells
            searched. hnsw_m, ef_search: HNSW links per node and search breadth.
        threads: faiss OpenMP threads (None: faiss's default).
    """

    def __init__(self, dim: int = 512, metric: str = "ip", index: str = "flat",
                 backend: str = "faiss", nlist: int = 1024, nprobe: int = 16,
                 hnsw_m: int = 32, ef_search: int = 64, threads: int | None = None):
        if metric not in METRICS:
            raise ValueError(f"metric {metric!r}: valid: {', '.join(METRICS)}")
        if index not in INDEXES:
            raise ValueError(f"index {index!r}: valid: {', '.join(INDEXES)}")
        if backend not in ("faiss", "numpy"):
            raise ValueError(f"backend {backend!r}: valid: faiss, numpy")
        if backend == "numpy" and index != "flat":
            raise ValueError("the numpy backend is exact brute force: index must be 'flat'")
        self.dim, self.metric, self.kind, self.backend = int(dim), metric, index, backend
        self.nlist, self.nprobe, self.hnsw_m, self.ef_search = nlist, nprobe, hnsw_m, ef_search
        self._ids = np.zeros(0, np.int64)
        self._vecs = np.zeros((0, self.dim), np.float32)  # numpy backend only
        self._index = None
        if backend == "faiss":
            import faiss

            if threads:
                faiss.omp_set_num_threads(int(threads))
            self._index = self._make_index(faiss)

    def _make_index(self, faiss):
        mt = faiss.METRIC_INNER_PRODUCT if self.metric == "ip" else faiss.METRIC_L2
        if self.kind == "flat":
            return faiss.IndexFlat(self.dim, mt)
        if self.kind == "hnsw":
            idx = faiss.IndexHNSWFlat(self.dim, self.hnsw_m, mt)
            idx.hnsw.efSearch = self.ef_search
            return idx
        quant = faiss.IndexFlat(self.dim, mt)
        idx = faiss.IndexIVFFlat(quant, self.dim, self.nlist, mt)
        idx.nprobe = self.nprobe
        self._quantizer = quant  # the IVF index does not own it: keep it alive
        return idx

    def __len__(self) -> int:
        return len(self._ids)

    def _check(self, x) -> np.ndarray:
        x = np.ascontiguousarray(x, np.float32)
        if x.ndim != 2 or x.shape[1] != self.dim:
            raise ValueError(f"vectors must be (N, {self.dim}), got {x.shape}")
        if not np.isfinite(x).all():
            raise ValueError("vectors contain NaN or infinite values")
        return x

    def add(self, vectors, ids=None) -> None:
        """Add (N, dim) vectors with int64 ids (default: running numbers from len(self))."""
        x = self._check(vectors)
        ids = (np.arange(len(self), len(self) + len(x), dtype=np.int64) if ids is None
               else np.asarray(ids, np.int64))
        if ids.shape != (len(x),):
            raise ValueError(f"{len(ids)} ids for {len(x)} vectors")
        if self._index is not None:
            if self.kind == "ivf" and not self._index.is_trained:
                if len(x) < self.nlist:
                    raise ValueError(f"an IVF index with {self.nlist} cells needs at least "
                                     f"{self.nlist} vectors in its first add, got {len(x)}")
                self._index.train(x)
            self._index.add(x)
        else:
            self._vecs = np.concatenate([self._vecs, x])
        self._ids = np.concatenate([self._ids, ids])

    def search(self, queries, k: int = 10) -> tuple[np.ndarray, np.ndarray]:
        """(scores (Q, k) float32, ids (Q, k) int64), best first.

        Scores: inner product (ip) or squared L2 distance (l2). With fewer than k
        vectors the missing places hold id -1 and score -inf (ip) / +inf (l2).
        """
        q = self._check(queries)
        k = int(k)
        if k < 1:
            raise ValueError(f"k must be >= 1, got {k}")
        if self._index is not None:
            scores, pos = self._index.search(q, k)
            ids = np.where(pos >= 0, self._ids[np.clip(pos, 0, None)] if len(self._ids)
                           else -1, -1)
            bad = pos < 0
            scores = np.where(bad, -np.inf if self.metric == "ip" else np.inf, scores)
            return scores.astype(np.float32), ids.astype(np.int64)
        return brute_force_search(self._vecs, q, k, self.metric, self._ids)

    def save(self, path: str | Path) -> None:
        """Write the vectors and ids (``.npz``; the index is rebuilt on load)."""
        vecs = self.vectors()
        np.savez(path, vectors=vecs, ids=self._ids, metric=self.metric, dim=self.dim)

    def vectors(self) -> np.ndarray:
        """All vectors, (N, dim) float32, in insertion order."""
        if self._index is None:
            return self._vecs
        if self.kind == "flat":
            return self._index.reconstruct_n(0, len(self))
        raise ValueError("approximate indexes do not keep the vectors retrievable here")


def brute_force_search(vectors, queries, k: int, metric: str = "ip",
                       ids=None) -> tuple[np.ndarray, np.ndarray]:
    """Exact k-NN in numpy: (scores, ids) as ``Gallery.search``; ties by smaller id."""
    g = np.asarray(vectors, np.float32)
    q = np.asarray(queries, np.float32)
    ids = np.arange(len(g), dtype=np.int64) if ids is None else np.asarray(ids, np.int64)
    n = len(g)
    kk = min(k, n)
    if metric == "ip":
        s = q @ g.T
        key = -s
    else:
        s = (q * q).sum(1)[:, None] + (g * g).sum(1)[None, :] - 2.0 * (q @ g.T)
        s = np.maximum(s, 0.0)
        key = s
    out_s = np.full((len(q), k), -np.inf if metric == "ip" else np.inf, np.float32)
    out_i = np.full((len(q), k), -1, np.int64)
    if kk == 0:
        return out_s, out_i
    if kk < n:
        part = np.argpartition(key, kk - 1, axis=1)[:, :kk]
    else:
        part = np.broadcast_to(np.arange(n), (len(q), n))
    pk = np.take_along_axis(key, part, 1)
    order = np.lexsort((ids[part], pk), axis=1)
    top = np.take_along_axis(part, order, 1)
    out_s[:, :kk] = np.take_along_axis(s, top, 1)
    out_i[:, :kk] = ids[top]
    return out_s, out_i
