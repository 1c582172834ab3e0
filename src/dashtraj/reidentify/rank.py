"""Ranking the tracks of a sightings database by appearance (``dashtraj reid query``).

The gallery is every embedded crop whose detection belongs to a confirmed track
(`dashtraj.store.EmbeddingSet`), minus the query's own track when the query is a
track. Distances are cosine distances ``d = 1 − q·g`` in [0, 2] between L2-normalised
vectors, from an exact inner-product search of `dashtraj.reid.gallery` (faiss flat;
``backend="numpy"`` is the brute force that gives the same ranking).

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


def rank_tracks(query, gallery: EmbeddingSet, k: int = 10, aggregate: str = DEFAULT_AGGREGATE,
                exclude: tuple[int, int] | None = None, backend: str = "faiss",
                threads: int | None = None) -> TrackRanking:
    """The ``k`` tracks of ``gallery`` closest to ``query`` (module docstring).

    Args:
        query: (D,) unit vector (`query_vector`).
        gallery: the database's embeddings of one model.
        k: tracks to return (>= 1; fewer when the gallery has fewer).
        aggregate: a name in `dashtraj.reidentify.decision.AGGREGATORS`.
        exclude: (observer_id, track_id) left out of the gallery (the query's track).
        backend: "faiss" or "numpy" (`dashtraj.reid.gallery.Gallery`).
        threads: faiss threads (None: faiss's default).

    Raises:
        RankError: k < 1; the query's size is not the gallery's; no tracked crop left.
        ReidDecisionError: an unknown aggregator (the message lists the valid ones).
    """
    fn = aggregator(aggregate)
    if int(k) < 1:
        raise RankError(f"k must be >= 1, got {k}")
    q = np.asarray(query, dtype=np.float32).reshape(-1)
    if q.shape[0] != gallery.dim:
        raise RankError(f"the query vector is {q.shape[0]}-d, the database's embeddings of "
                        f"{gallery.model} are {gallery.dim}-d")
    keep = gallery.track_id >= 0
    if exclude is not None:
        keep &= ~((gallery.observer_id == exclude[0]) & (gallery.track_id == exclude[1]))
    rows = np.flatnonzero(keep)
    if len(rows) == 0:
        raise RankError("the database has no embedded crops of a confirmed track to search"
                        + (" besides the query's track" if exclude is not None else ""))
    g = Gallery(gallery.dim, metric="ip", index="flat", backend=backend, threads=threads)
    g.add(l2_normalize(gallery.vectors[rows]), ids=rows)
    scores, ids = g.search(q[None, :], k=len(rows))  # exact: every gallery crop
    dist = np.empty(len(gallery), np.float64)
    dist[ids[0]] = np.clip(1.0 - scores[0].astype(np.float64), 0.0, 2.0)
    pairs = np.stack([gallery.observer_id[rows], gallery.track_id[rows]], axis=1)
    uniq, inv = np.unique(pairs, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    order = np.argsort(inv, kind="stable")
    bounds = np.searchsorted(inv[order], np.arange(len(uniq) + 1))
    cand = []
    for j in range(len(uniq)):
        members = rows[order[bounds[j]:bounds[j + 1]]]
        d = dist[members]
        cand.append((float(fn(d)), int(uniq[j, 0]), int(uniq[j, 1]), members, d))
    cand.sort(key=lambda c: (c[0], c[1], c[2]))
    out = []
    for r, (agg, obs, trk, members, d) in enumerate(cand[:int(k)], start=1):
        b = int(members[int(np.argmin(d))])
        truth = int(_majority(gallery.truth_vehicle_id[members]))
        out.append(RankedTrack(
            rank=r, observer_id=obs, track_id=trk, distance=agg, crops=len(members),
            best_frame=int(gallery.frame[b]), best_idx=int(gallery.idx[b]),
            best_t=float(gallery.t[b]), best_distance=float(dist[b]),
            vehicle_class=str(_majority([gallery.vehicle_class[i] for i in members])),
            first_t=float(gallery.t[members].min()), last_t=float(gallery.t[members].max()),
            truth_vehicle_id=None if truth < 0 else truth))
    return TrackRanking(tracks=tuple(out), aggregate=aggregate, tracks_searched=len(uniq),
                        crops_searched=len(rows))
