"""Ranking the tracks of a sightings database by appearance (``dashtraj reid query``).

The gallery is every embedded crop whose detection belongs to a confirmed track
(`dashtraj.store.EmbeddingSet`), minus the query's own track when the query is a
track. Distances are cosine distances ``d = 1 − q·g`` in [0, 2] between L2-normalised
vectors, from an exact inner-product search of `dashtraj.reid.gallery` (faiss flat;
``backend="numpy"`` is the brute force that gives the same ranking). The search looks
at the nearest crops first and widens (x4) until the top k tracks are provably
exact: every aggregator below is at least the track's closest-crop distance, so a
track without a crop among those searched cannot beat a k-th candidate that is closer
than the farthest crop searched.

The query vector (`query_vector`):

- an image: its embedding;
- a track: the **mean of its crops' L2-normalised embeddings, re-normalised** to unit
  length. Averaging cancels what differs from crop to crop (viewpoint, truncation,
  blur, JPEG noise) and keeps what the crops share, the vehicle's appearance; it is
  one search instead of one per query crop.

A track's distance aggregates the distances of its crops (``aggregate``, the names of
`dashtraj.reidentify.decision.AGGREGATORS`):

- ``min``: the track's closest crop. A track is as close as its best view (another
  observer sees the vehicle from other sides and ranges, so most of its crops look
  unlike the query), but one lucky crop of a look-alike decides too, and long tracks
  get more draws.
- ``mean`` / ``median``: every crop counts, so the truncated, blurred and far crops of
  the right vehicle push it down.
- ``kmin-mean`` (the default here): the mean of the closest half of the track's crops
  (ceil(n/2)): the views that match, without betting on a single one.

Measured with the shipped model on three perception runs (oracle detector, 320 x 180,
town01 seed 2 with 4 observers, town01 seed 3 and town10 seed 0 with 6 observers and
20 agents): querying with each of the 59 tracks whose vehicle another observer also
tracked (13 to 39 other tracks each), the best rank of such a track was

    aggregate   rank-1   top-5   mean best rank (chance: 11.3)
    kmin-mean    46 %     73 %    4.36
    min          42 %     73 %    4.54
    mean         41 %     69 %    4.51
    median       34 %     69 %    4.49

(`_partner_ranks` in tests/reid/test_query_db.py). The differences are a few queries:
all four are offered; ``kmin-mean`` led on every figure.

Ties are broken by the smaller (observer_id, track_id).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dashtraj.errors import DashtrajError
from dashtraj.reid.evaluate import l2_normalize
from dashtraj.reid.gallery import Gallery
from dashtraj.reidentify.decision import aggregator
from dashtraj.store import EmbeddingSet

DEFAULT_AGGREGATE = "kmin-mean"
"""Track aggregation of `rank_tracks` unless told otherwise (module docstring)."""


class RankError(DashtrajError):
    """A query that cannot be answered (no gallery, a zero or malformed query vector)."""


@dataclass(frozen=True, slots=True)
class RankedTrack:
    """One track of the ranking.

    Attributes:
        rank: 1 for the closest track.
        observer_id, track_id: the track.
        distance: its aggregated cosine distance to the query.
        crops: its embedded crops.
        best_frame, best_idx, best_t, best_distance: its crop closest to the query
            (frame, index in the frame, seconds, cosine distance).
        vehicle_class: the most frequent class of its crops.
        first_t, last_t: seconds of its first and last embedded crop.
        truth_vehicle_id: the renderer's vehicle most of its crops show (None when
            unknown; evaluation only).
    """

    rank: int
    observer_id: int
    track_id: int
    distance: float
    crops: int
    best_frame: int
    best_idx: int
    best_t: float
    best_distance: float
    vehicle_class: str
    first_t: float
    last_t: float
    truth_vehicle_id: int | None

    def to_dict(self) -> dict:
        return {f: getattr(self, f) for f in self.__slots__}


@dataclass(frozen=True, slots=True)
class TrackRanking:
    """The answer of `rank_tracks`: the top tracks and what was searched."""

    tracks: tuple[RankedTrack, ...]
    aggregate: str
    tracks_searched: int
    crops_searched: int


def query_vector(vectors) -> np.ndarray:
    """(D,) unit vector: the mean of the L2-normalised rows of (N, D) ``vectors``,
    re-normalised (one row: that row, normalised).

    Raises:
        RankError: no rows, non-finite values, or rows that cancel out.
    """
    v = np.asarray(vectors, dtype=np.float64)
    if v.ndim != 2 or len(v) == 0:
        raise RankError(f"a query needs (N, D) vectors with N >= 1, got shape {v.shape}")
    if not np.isfinite(v).all():
        raise RankError("the query's vectors hold NaN or infinite values")
    m = l2_normalize(v).mean(axis=0)
    n = float(np.linalg.norm(m))
    if n < 1e-6:
        raise RankError("the query's crop embeddings cancel out (their mean is zero)")
    return (m / n).astype(np.float32)


def _majority(values) -> object:
    vals, counts = np.unique(np.asarray(values), return_counts=True)
    return vals[int(np.argmax(counts))]


class TrackGallery:
    """The embedded crops of confirmed tracks, indexed once for many queries.

    Args:
        embeddings: the database's embeddings of one model (`SightingsDB.embeddings`);
            rows of unconfirmed detections (track id -1) are left out.
        backend: "faiss" or "numpy" (`dashtraj.reid.gallery.Gallery`, flat: exact).
        threads: faiss threads (None: faiss's default).

    Raises:
        RankError: no embedded crop of a confirmed track.
    """

    def __init__(self, embeddings: EmbeddingSet, backend: str = "faiss",
                 threads: int | None = None):
        e = embeddings
        rows = np.flatnonzero(e.track_id >= 0)
        if len(rows) == 0:
            raise RankError("the database has no embedded crops of a confirmed track to search")
        self.embeddings = e
        self.rows = rows
        v = e.vectors if len(rows) == len(e) else e.vectors[rows]
        norms = np.linalg.norm(v, axis=1, keepdims=True)
        if not np.allclose(norms, 1.0, atol=1e-5):  # the embedder's are unit already
            v = v / np.maximum(norms, 1e-12)
        self.vectors = np.ascontiguousarray(v, dtype=np.float32)
        self.index = Gallery(e.dim, metric="ip", index="flat", backend=backend, threads=threads)
        self.index.add(self.vectors, ids=np.arange(len(rows)))  # ids: positions in rows
        pairs = np.stack([e.observer_id[rows], e.track_id[rows]], axis=1)
        self.tracks, inv = np.unique(pairs, axis=0, return_inverse=True)
        self._inv = inv.reshape(-1)
        self._order = np.argsort(self._inv, kind="stable")
        self._bounds = np.searchsorted(self._inv[self._order], np.arange(len(self.tracks) + 1))

    def _track(self, key: tuple[int, int]) -> int | None:
        hit = np.flatnonzero((self.tracks[:, 0] == key[0]) & (self.tracks[:, 1] == key[1]))
        return int(hit[0]) if len(hit) else None

    def rank(self, query, k: int = 10, aggregate: str = DEFAULT_AGGREGATE,
             exclude: tuple[int, int] | None = None) -> TrackRanking:
        """The ``k`` tracks closest to ``query`` (module docstring).

        Args:
            query: (D,) unit vector (`query_vector`).
            k: tracks to return (>= 1; fewer when the gallery has fewer).
            aggregate: a name in `dashtraj.reidentify.decision.AGGREGATORS`.
            exclude: (observer_id, track_id) left out (the query's own track).

        Raises:
            RankError: k < 1; the query's size is not the gallery's; no track left.
            ReidDecisionError: an unknown aggregator (the message lists the valid ones).
        """
        fn = aggregator(aggregate)
        e = self.embeddings
        if int(k) < 1:
            raise RankError(f"k must be >= 1, got {k}")
        q = np.asarray(query, dtype=np.float32).reshape(-1)
        if q.shape[0] != e.dim:
            raise RankError(f"the query vector is {q.shape[0]}-d, the database's embeddings "
                            f"of {e.model} are {e.dim}-d")
        skip = self._track(exclude) if exclude is not None else None
        n_tracks = len(self.tracks) - (skip is not None)
        if n_tracks == 0:
            raise RankError("the database has no embedded crops of a confirmed track to "
                            "search besides the query's track")
        n_crops = len(self.rows) - (0 if skip is None else
                                    int(self._bounds[skip + 1] - self._bounds[skip]))
        k_eff = min(int(k), n_tracks)
        q64 = q.astype(np.float64)
        # Search the kk nearest crops; their tracks are the candidates, aggregated exactly
        # over all their crops. Every aggregator is >= the track's closest crop, so a track
        # with no crop among the kk has a distance >= the kk-th crop's: when the k-th
        # candidate is closer than that, the top k are exact; otherwise kk grows (x4).
        kk = min(len(self.rows), max(256, 32 * int(k)))
        scored: dict[int, tuple[float, np.ndarray, np.ndarray]] = {}
        while True:
            scores, pos = self.index.search(q[None, :], kk)
            found = pos[0][pos[0] >= 0]
            for j in np.unique(self._inv[found]).tolist():
                if j not in scored and j != skip:
                    members = self._order[self._bounds[j]:self._bounds[j + 1]]
                    d = np.clip(1.0 - self.vectors[members].astype(np.float64) @ q64, 0.0, 2.0)
                    scored[j] = (float(fn(d)), members, d)
            if kk >= len(self.rows):
                break
            if len(scored) >= k_eff:
                kth = sorted(v[0] for v in scored.values())[k_eff - 1]
                if kth < 1.0 - float(scores[0, -1]) - 1e-6:
                    break
            kk = min(len(self.rows), 4 * kk)
        cand = sorted(((agg, int(self.tracks[j, 0]), int(self.tracks[j, 1]), self.rows[m], d)
                       for j, (agg, m, d) in scored.items()), key=lambda c: c[:3])
        out = []
        for r, (agg, obs, trk, members, d) in enumerate(cand[:k_eff], start=1):
            b = int(members[int(np.argmin(d))])
            truth = int(_majority(e.truth_vehicle_id[members]))
            out.append(RankedTrack(
                rank=r, observer_id=obs, track_id=trk, distance=agg, crops=len(members),
                best_frame=int(e.frame[b]), best_idx=int(e.idx[b]), best_t=float(e.t[b]),
                best_distance=float(d.min()),
                vehicle_class=str(_majority([e.vehicle_class[i] for i in members])),
                first_t=float(e.t[members].min()), last_t=float(e.t[members].max()),
                truth_vehicle_id=None if truth < 0 else truth))
        return TrackRanking(tracks=tuple(out), aggregate=aggregate, tracks_searched=n_tracks,
                            crops_searched=n_crops)


def rank_tracks(query, gallery: EmbeddingSet, k: int = 10, aggregate: str = DEFAULT_AGGREGATE,
                exclude: tuple[int, int] | None = None, backend: str = "faiss",
                threads: int | None = None) -> TrackRanking:
    """The ``k`` tracks of ``gallery`` closest to ``query``: one query on a `TrackGallery`
    built for it (build one yourself for many queries); arguments and errors as there."""
    return TrackGallery(gallery, backend=backend, threads=threads).rank(
        query, k=k, aggregate=aggregate, exclude=exclude)
