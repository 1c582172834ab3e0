"""Track ranking (`dashtraj.reidentify.rank`) against an independent brute force on a
gallery large enough that the search widens several times before the top k are exact."""

from __future__ import annotations

import numpy as np
import pytest

from dashtraj.reidentify.decision import ReidDecisionError
from dashtraj.reidentify.rank import RankError, TrackGallery, query_vector, rank_tracks
from dashtraj.store import EmbeddingSet

pytest.importorskip("faiss")


def _set(n_tracks: int = 300, per_track: int = 30, ids: int = 60, seed: int = 0) -> EmbeddingSet:
    """Tracks of 30 crops each: 60 identities, each crop a noisy view of its identity
    (cosine to the centre ≈ 0.6, so tracks overlap and crops of one track spread), plus
    40 unconfirmed detections (track -1)."""
    rng = np.random.default_rng(seed)
    centres = rng.normal(size=(ids, 64))
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    n = n_tracks * per_track + 40
    obs = np.r_[np.repeat(np.arange(n_tracks) % 7, per_track), np.zeros(40, int)]
    trk = np.r_[np.repeat(np.arange(n_tracks), per_track), -np.ones(40, int)]
    ident = np.r_[np.repeat(rng.integers(0, ids, n_tracks), per_track), np.zeros(40, int)]
    v = centres[ident] + 0.15 * rng.normal(size=(n, 64))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return EmbeddingSet(
        model="m", model_sha256="s" * 64, dim=64, observer_id=obs.astype(np.int64),
        frame=np.arange(n, dtype=np.int64), idx=np.zeros(n, np.int64),
        track_id=trk.astype(np.int64), t=np.arange(n) * 0.1, box=np.zeros((n, 4)),
        vehicle_class=("car",) * n, distance_m=np.full(n, 8.0),
        truth_vehicle_id=ident.astype(np.int64), vectors=v.astype(np.float32))


def _brute(e: EmbeddingSet, q: np.ndarray, agg: str, exclude) -> list[tuple[float, int, int]]:
    fns = {"min": np.min, "mean": np.mean, "median": np.median,
           "kmin-mean": lambda d: np.sort(d)[:(len(d) + 1) // 2].mean()}
    out = []
    for o, t in sorted({(int(a), int(b)) for a, b in zip(e.observer_id, e.track_id,
                                                            strict=True) if b >= 0}):
        if (o, t) == exclude:
            continue
        m = (e.observer_id == o) & (e.track_id == t)
        d = 1.0 - e.vectors[m].astype(np.float64) @ q.astype(np.float64)
        out.append((float(fns[agg](d)), o, t))
    return sorted(out)


@pytest.mark.parametrize("agg", ["min", "mean", "median", "kmin-mean"])
def test_top_k_equals_brute_force_for_every_aggregator(agg):
    e = _set()
    index = TrackGallery(e)
    for qt in (0, 17, 123, 299):
        m = e.track_id == qt
        ex = (int(e.observer_id[m][0]), qt)
        q = query_vector(e.vectors[m])
        for k in (1, 3, 10):
            got = index.rank(q, k=k, aggregate=agg, exclude=ex)
            ref = _brute(e, q, agg, ex)[:k]
            assert [(t.observer_id, t.track_id) for t in got.tracks] == [r[1:] for r in ref]
            np.testing.assert_allclose([t.distance for t in got.tracks], [r[0] for r in ref],
                                       atol=1e-6)
            assert (got.tracks_searched, got.crops_searched) == (299, 299 * 30)
        # the numpy backend answers the same
        b = rank_tracks(q, e, k=10, aggregate=agg, exclude=ex, backend="numpy")
        assert [(t.observer_id, t.track_id) for t in b.tracks] == [
            (t.observer_id, t.track_id) for t in index.rank(q, 10, agg, ex).tracks]


def test_ranked_track_fields_and_a_crop_query():
    e = _set()
    i = 4321  # a crop of track 144: as a query it is its own track's closest crop
    r = rank_tracks(e.vectors[i], e, k=2, aggregate="min")
    top = r.tracks[0]
    assert (top.rank, top.track_id, top.best_frame, top.crops) == (1, 144, i, 30)
    assert top.distance == top.best_distance == pytest.approx(0.0, abs=1e-6)
    assert (top.first_t, top.last_t) == pytest.approx((4320 * 0.1, 4349 * 0.1))
    assert top.truth_vehicle_id == int(e.truth_vehicle_id[i]) and top.vehicle_class == "car"
    assert r.tracks[1].rank == 2 and r.tracks[1].distance >= top.distance
    assert len(rank_tracks(e.vectors[i], e, k=1000).tracks) == 300  # k beyond the gallery


def test_bad_queries_are_named():
    e = _set(n_tracks=2, per_track=3)
    with pytest.raises(RankError, match="k must be >= 1"):
        rank_tracks(e.vectors[0], e, k=0)
    with pytest.raises(RankError, match="the query vector is 3-d"):
        rank_tracks(np.ones(3), e)
    with pytest.raises(ReidDecisionError, match="valid: min, mean, median, kmin-mean"):
        rank_tracks(e.vectors[0], e, aggregate="max")
    one = _set(n_tracks=1, per_track=3)
    with pytest.raises(RankError, match="besides the query's track"):
        rank_tracks(one.vectors[0], one, exclude=(0, 0))
    with pytest.raises(RankError, match="cancel out"):
        query_vector(np.stack([e.vectors[0], -e.vectors[0]]))
    with pytest.raises(RankError, match="N >= 1"):
        query_vector(np.zeros((0, 64)))
