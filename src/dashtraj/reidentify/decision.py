"""Per-track "target or not" decisions from appearance distances, and their threshold.

The paper (Algorithm 1, ``calc_traj``) compares the query crop with every gallery
crop and accepts single detections. Here each observer's *track* is decided as a
whole: the distances of its detections to the query are aggregated into one track
distance, and the track is the target when that distance is at most a threshold.
The threshold is calibrated on embeddings of TRAINING identities
(`calibrate_threshold`), never on the test run.

Distances are cosine distances between L2-normalised embeddings,
``d = 1 − q·g`` in [0, 2] (= ½‖q − g‖²); the embedder of `dashtraj.reid` returns
L2-normalised vectors (512-d for one exported model, more for an ensemble).

Aggregation (`AGGREGATORS`, chosen by name; default ``median``):

- ``min``: the best single crop. One lucky crop decides, and the chance that some
  crop of a look-alike's long track falls below the threshold grows with the track's
  length (an extreme value of n draws): false matches.
- ``mean``: every crop counts, so truncated, occluded or blurred crops of the true
  target (which only ever *raise* its distance) pull a true track above the
  threshold: missed matches.
- ``median``: robust to both tails -- up to half the crops may be bad either way --
  and, with one or two crops, equal to their mean. The default.
- ``kmin-mean``: mean of the k = ceil(n/2) smallest: between ``min`` and ``median``,
  for models whose bad crops are frequent.

What a track's distance is made of (`Recipe`, recorded in the `Calibration` so that
the run decides exactly as the threshold was calibrated):

- the crops used (`adequate_crops`): a crop whose box is shorter than ``min_box_px``
  or comes within ``border_px`` of the image border (a vehicle cut by the frame: half
  a car looks like any car) is left out of both the query and the gallery tracks; a
  track without any adequate crop is not decided (never the target);
- the query (`QUERIES`): ``crop``, the target's first crop within 15 m as in
  ``calc_traj`` (``veh_t1.image``); or ``track``, *query expansion*: the mean of the
  L2-normalised embeddings of the adequate crops of the query's own track (the crops
  the tracker joined to the query crop; with it if it is adequate), re-normalised. In
  a run only the track's crops within the threshold of the query crop are averaged
  (`dashtraj.reidentify.vision.expansion_crops`: a tracker can switch vehicles);
  calibration's groups are truth-pure and are averaged whole.
  Averaging cancels what differs from crop to crop (viewpoint, blur, truncation) and
  keeps the vehicle's appearance, so a weak embedding separates tracks better than
  it separates crops.

Calibration forms the same decisions the run will make: a query is one embedding
of identity A seen by camera c; a gallery "track" is the group of embeddings of one
identity by one camera c' ≠ c (the VeRi protocol's cross-camera rule); its
aggregated distance is a positive pair when the identity is A, a negative pair
otherwise. The threshold is chosen by `RULES`:

- ``eer``: where the false-accept rate on negatives equals the false-reject rate on
  positives (the equal error rate point),
- ``precision``: the highest recall whose precision on the calibration pairs is at
  least `target_precision` (the pairs' balance -- one identity among many -- is the
  run's: one target among dozens of tracks).
- ``far``: the highest recall whose false-accept rate on the negative pairs is at
  most `max_far`: a bound on how many of a run's other tracks pass the threshold
  (``max_far`` × tracks in range) and are left to the gate, for a model that reaches
  no useful recall at precision 0.99.

Candidate thresholds are the midpoints between consecutive distinct pair distances
(so a threshold never sits on a training distance), plus one below the smallest
and one above the largest.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass

import numpy as np

from dashtraj.errors import DashtrajError


class ReidDecisionError(DashtrajError, ValueError):
    """Bad input to a decision or a calibration (the message names it)."""


def _kmin_mean(d: np.ndarray) -> np.ndarray:
    k = math.ceil(d.shape[-1] / 2)
    return np.sort(d, axis=-1)[..., :k].mean(axis=-1)


AGGREGATORS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "min": lambda d: d.min(axis=-1),
    "mean": lambda d: d.mean(axis=-1),
    "median": lambda d: np.median(d, axis=-1),
    "kmin-mean": _kmin_mean,
}
"""Track aggregators by name: (..., n) detection distances → (...) track distances."""

QUERIES: tuple[str, ...] = ("crop", "track")
"""What the query is (module docstring): one crop (the paper) or the query's track."""

RULES: tuple[str, ...] = ("eer", "precision", "far")
"""Threshold rules of `calibrate_threshold` / `threshold_from_pairs`."""


def aggregator(name: str) -> Callable[[np.ndarray], np.ndarray]:
    """The aggregator called `name`; raises ReidDecisionError listing the valid ones."""
    try:
        return AGGREGATORS[name]
    except KeyError:
        raise ReidDecisionError(f"unknown aggregator {name!r}; valid: "
                                f"{', '.join(AGGREGATORS)}") from None


def cosine_distances(query: np.ndarray, gallery: np.ndarray, atol: float = 1e-3) -> np.ndarray:
    """Cosine distances 1 − q·g of L2-normalised embeddings.

    Args:
        query: (D,) or (M, D) float, unit norm.
        gallery: (N, D) float, unit norm.
        atol: tolerance on the norms.

    Returns:
        (N,) for one query, (M, N) for many; float64 in [0, 2].

    Raises:
        ReidDecisionError: shapes disagree, a value is not finite, or a row is not
            unit norm (normalise first: the decision threshold assumes it).
    """
    q = np.asarray(query, dtype=np.float64)
    g = np.asarray(gallery, dtype=np.float64)
    one = q.ndim == 1
    q2 = q[None, :] if one else q
    if q2.ndim != 2 or g.ndim != 2 or q2.shape[1] != g.shape[1]:
        raise ReidDecisionError(f"cosine_distances: query {q.shape} and gallery {g.shape} "
                                "must be (D,) or (M, D) and (N, D)")
    for name, a in (("query", q2), ("gallery", g)):
        if not np.isfinite(a).all():
            raise ReidDecisionError(f"cosine_distances: {name} has non-finite values")
        n = np.linalg.norm(a, axis=1)
        bad = np.flatnonzero(np.abs(n - 1.0) > atol)
        if len(bad):
            raise ReidDecisionError(f"cosine_distances: {name} row {int(bad[0])} has norm "
                                    f"{n[bad[0]]:.4f}, expected L2-normalised embeddings")
    d = np.clip(1.0 - q2 @ g.T, 0.0, 2.0)
    return d[0] if one else d


@dataclass(frozen=True, slots=True)
class Recipe:
    """How a track's distance to the query is formed (module docstring).

    Attributes:
        aggregate: a name in `AGGREGATORS`.
        query: a name in `QUERIES`.
        min_box_px: crops whose box is shorter than this are not used, pixels (0: all).
        border_px: crops whose box comes within this of the image border are not
            used, pixels (None: truncated crops are used too).
    """

    aggregate: str = "median"
    query: str = "crop"
    min_box_px: float = 0.0
    border_px: float | None = None

    def __post_init__(self) -> None:
        aggregator(self.aggregate)
        if self.query not in QUERIES:
            raise ReidDecisionError(f"unknown query {self.query!r}; valid: {', '.join(QUERIES)}")
        if not (math.isfinite(self.min_box_px) and self.min_box_px >= 0):
            raise ReidDecisionError(f"min_box_px must be >= 0, got {self.min_box_px!r}")
        if self.border_px is not None and not (math.isfinite(self.border_px)
                                               and self.border_px >= 0):
            raise ReidDecisionError(f"border_px must be >= 0 or None, got {self.border_px!r}")


PAPER_RECIPE = Recipe("median", "crop", 0.0, None)
"""The paper's query (one crop) and every crop, with the median over each track."""

EXPANDED_RECIPE = Recipe("median", "track", 24.0, 2.0)
"""Query expansion with the query's track, crops at least 24 px tall (a car at ≈ 13 m
in a 640-px-wide, 90° frame) and at least 2 px from the image border; the default of
``dashtraj reid-threshold``."""


def adequate_crops(boxes: np.ndarray, width_px: int, height_px: int,
                   recipe: Recipe) -> np.ndarray:
    """(N,) bool: which crops `recipe` uses.

    Args:
        boxes: (N, 4) x0, y0, x1, y1, image pixels.
        width_px, height_px: the image size, pixels.
        recipe: its ``min_box_px`` and ``border_px``.

    Example:
        >>> adequate_crops(np.array([[0, 10, 50, 60], [100, 10, 150, 30],
        ...                          [100, 10, 150, 60]]), 640, 360, EXPANDED_RECIPE).tolist()
        [False, False, True]
    """
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    ok = (b[:, 3] - b[:, 1]) >= recipe.min_box_px
    if recipe.border_px is not None:
        m = recipe.border_px
        ok &= ((b[:, 0] > m) & (b[:, 1] > m) & (b[:, 2] < width_px - m)
               & (b[:, 3] < height_px - m))
    return ok


@dataclass(frozen=True, slots=True)
class TrackDecision:
    """The decision for one track.

    Attributes:
        key: the track's key, e.g. (observer_id, track_id).
        distance: the aggregated cosine distance to the query.
        detections: how many detection distances it aggregates.
        target: distance <= threshold.
    """

    key: Hashable
    distance: float
    detections: int
    target: bool


def decide_tracks(distances: np.ndarray, keys: Sequence[Hashable], threshold: float,
                  aggregate: str = "median") -> list[TrackDecision]:
    """Aggregate detection distances per track and decide "target" per track.

    Args:
        distances: (N,) cosine distances of N detections to the query.
        keys: N track keys (hashable, e.g. (observer_id, track_id)), one per detection.
        threshold: a track is the target when its aggregated distance is <= this.
        aggregate: a name in `AGGREGATORS`.

    Returns:
        One `TrackDecision` per distinct key, in order of first appearance.

    Raises:
        ReidDecisionError: lengths differ, a distance or the threshold is not finite,
            or the aggregator is unknown.

    Example:
        >>> [d.target for d in decide_tracks(np.array([0.1, 0.9, 0.2, 0.8]),
        ...                                  ["a", "b", "a", "b"], 0.5)]
        [True, False]
    """
    fn = aggregator(aggregate)
    d = np.asarray(distances, dtype=np.float64)
    if d.ndim != 1 or len(d) != len(keys):
        raise ReidDecisionError(f"decide_tracks: {d.shape} distances for {len(keys)} keys")
    if not np.isfinite(d).all():
        raise ReidDecisionError(f"decide_tracks: distance {int(np.flatnonzero(~np.isfinite(d))[0])}"
                                " is not finite")
    if not math.isfinite(threshold):
        raise ReidDecisionError(f"decide_tracks: threshold must be finite, got {threshold!r}")
    rows: dict[Hashable, list[int]] = {}
    for i, k in enumerate(keys):
        rows.setdefault(k, []).append(i)
    out = []
    for k, idx in rows.items():
        agg = float(fn(d[idx]))
        out.append(TrackDecision(k, agg, len(idx), bool(agg <= threshold)))
    return out


def appearance_splits(distances: np.ndarray, threshold: float, min_crops: int = 3,
                      min_step: float = 0.2, margin: float = 0.0) -> list[int]:
    """Where one track's crops change vehicle, by their distances to the query.

    A tracker can swap two vehicles' identities where their boxes cross, or carry a
    track onto a neighbour after it lost its own: the track then holds the target's
    crops on one side of a moment and another vehicle's on the other, and one aggregate
    distance for the whole track either takes the other vehicle in or leaves the
    target's crops out. This finds those moments by binary segmentation of the crops'
    distances (in time order): the cut that maximises the CUSUM statistic
    |mean(left) - mean(right)| * sqrt(j (n - j) / n) is kept when one side's median is
    at most `threshold`, the other's above `threshold` + `margin`, they differ by at
    least `min_step`, and each side holds `min_crops` crops on its own side of
    `threshold`; each side is then cut again the same way.

    Args:
        distances: (n,) cosine distances to the query of one track's crops, in time
            order.
        threshold: the calibrated decision threshold.
        min_crops: the fewest crops on each side of a cut, and on that side of the
            threshold (>= 1): a crop or two of a vehicle seen at a bad angle is noise,
            not another vehicle.
        min_step: the least difference between the two sides' medians.
        margin: how far beyond `threshold` the other side's median must lie: a few
            crops just above it are the target at a harder angle more often than
            another vehicle.

    Returns:
        The sorted indices i where a new part starts (crops [.., i) and [i, ..)).

    Example:
        >>> appearance_splits(np.array([0.2, 0.18, 0.21, 0.19, 0.65, 0.7, 0.62]), 0.4)
        [4]
    """
    d = np.asarray(distances, dtype=np.float64).reshape(-1)
    if (min_crops < 1 or not math.isfinite(threshold) or not min_step >= 0
            or not margin >= 0):
        raise ReidDecisionError(f"appearance_splits: min_crops >= 1, finite threshold, "
                                f"min_step >= 0 and margin >= 0, got {min_crops!r}, "
                                f"{threshold!r}, {min_step!r}, {margin!r}")
    cuts: list[int] = []

    def split(a: int, b: int) -> None:
        n = b - a
        if n < 2 * min_crops:
            return
        x = d[a:b]
        c = np.cumsum(x)
        j = np.arange(min_crops, n - min_crops + 1)
        left, right = c[j - 1] / j, (c[-1] - c[j - 1]) / (n - j)
        stat = np.abs(left - right) * np.sqrt(j * (n - j) / n)
        k = int(j[int(np.argmax(stat))])
        ml, mr = float(np.median(x[:k])), float(np.median(x[k:]))
        near, far = (x[:k], x[k:]) if ml <= mr else (x[k:], x[:k])
        if (min(ml, mr) <= threshold and max(ml, mr) > threshold + margin
                and abs(ml - mr) >= min_step
                and (near <= threshold).sum() >= min_crops
                and (far > threshold).sum() >= min_crops):
            split(a, a + k)
            cuts.append(a + k)
            split(a + k, b)

    split(0, len(d))
    return sorted(cuts)

@dataclass(frozen=True, slots=True)
class Calibration:
    """A decision threshold and what it measured on the calibration pairs.

    Attributes:
        threshold: cosine distance; a track is the target when its aggregated
            distance is <= threshold.
        rule: the rule in `RULES` that chose it; aggregate: the aggregator's name.
        precision, recall: of "distance <= threshold" on the calibration pairs.
        false_accept_rate: share of negative pairs accepted.
        positives, negatives: pair counts.
        target_precision: the asked precision (rule "precision"), or None.
        max_far: the asked false-accept rate (rule "far"), or None.
        query, min_box_px, border_px: the `Recipe` the pairs were formed with (the
            run must decide the same way; files written before these fields existed
            read as the paper's single query crop and every crop).
    """

    threshold: float
    rule: str
    aggregate: str
    precision: float
    recall: float
    false_accept_rate: float
    positives: int
    negatives: int
    target_precision: float | None = None
    max_far: float | None = None
    query: str = "crop"
    min_box_px: float = 0.0
    border_px: float | None = None

    @property
    def recipe(self) -> Recipe:
        return Recipe(self.aggregate, self.query, self.min_box_px, self.border_px)

    def to_dict(self) -> dict:
        return {f: getattr(self, f) for f in self.__slots__}


def threshold_from_pairs(positive: np.ndarray, negative: np.ndarray, rule: str = "eer",
                         target_precision: float = 0.99,
                         aggregate: str = "median", max_far: float = 0.02) -> Calibration:
    """Pick a threshold from positive and negative pair distances (rules: module docstring).

    Args:
        positive: (P,) distances of same-identity pairs, P >= 1.
        negative: (Q,) distances of different-identity pairs, Q >= 1.
        rule: "eer" or "precision".
        target_precision: for rule "precision", in (0, 1].
        aggregate: recorded in the result (the aggregator that made the distances).
        max_far: for rule "far", in [0, 1].

    Returns:
        `Calibration`. With rule "precision" and no threshold reaching the target,
        the one of highest precision (then recall) is returned; its `precision`
        says so.

    Raises:
        ReidDecisionError: an empty or non-finite input, an unknown rule, or a
            target precision outside (0, 1].

    Example:
        >>> c = threshold_from_pairs(np.array([0.1, 0.2, 0.3, 0.6]),
        ...                          np.array([0.5, 0.7, 0.8, 0.9]))
        >>> round(c.threshold, 3), c.precision, c.recall
        (0.55, 0.75, 0.75)
    """
    if rule not in RULES:
        raise ReidDecisionError(f"unknown threshold rule {rule!r}; valid: {', '.join(RULES)}")
    pos = np.sort(np.asarray(positive, dtype=np.float64).ravel())
    neg = np.sort(np.asarray(negative, dtype=np.float64).ravel())
    for name, a in (("positive", pos), ("negative", neg)):
        if len(a) == 0:
            raise ReidDecisionError(f"calibration: no {name} pairs")
        if not np.isfinite(a).all():
            raise ReidDecisionError(f"calibration: a {name} pair distance is not finite")
    if rule == "precision" and not 0.0 < target_precision <= 1.0:
        raise ReidDecisionError(f"target precision must be in (0, 1], got {target_precision!r}")
    if rule == "far" and not 0.0 <= max_far <= 1.0:
        raise ReidDecisionError(f"max false-accept rate must be in [0, 1], got {max_far!r}")
    u = np.unique(np.concatenate([pos, neg]))
    cand = np.concatenate([[u[0] - 1e-6], (u[:-1] + u[1:]) / 2, [u[-1] + 1e-6]])
    tp = np.searchsorted(pos, cand, side="right").astype(np.float64)
    fp = np.searchsorted(neg, cand, side="right").astype(np.float64)
    recall = tp / len(pos)
    far = fp / len(neg)
    with np.errstate(invalid="ignore", divide="ignore"):
        precision = np.where(tp + fp > 0, tp / (tp + fp), 1.0)
    if rule == "eer":
        frr = 1.0 - recall
        # least |FAR − FRR|; then least mean error; then the lower threshold
        i = int(np.lexsort((cand, (far + frr) / 2, np.abs(far - frr)))[0])
        tgt = None
    else:
        ok = np.flatnonzero(precision >= target_precision - 1e-12)
        if len(ok):
            # highest recall; among equal recall the widest margin: the middle candidate
            best = recall[ok].max()
            same = ok[recall[ok] == best]
            i = int(same[len(same) // 2]) if len(same) > 1 else int(same[0])
        else:
            i = int(np.lexsort((-recall, -precision))[0])
        tgt = float(target_precision)
    if rule == "far":
        # far rises with the candidate: the last one within the bound (the first is 0)
        i = int(np.flatnonzero(far <= max_far + 1e-12)[-1])
        tgt = None
    return Calibration(float(cand[i]), rule, aggregate, float(precision[i]), float(recall[i]),
                       float(far[i]), len(pos), len(neg), tgt,
                       float(max_far) if rule == "far" else None)


def pair_distances(embeddings: np.ndarray, ids: Sequence[int], cams: Sequence[int],
                   aggregate: str = "median", max_queries: int | None = 2000,
                   rng: np.random.Generator | None = None,
                   chunk: int = 512, query: str = "crop") -> tuple[np.ndarray, np.ndarray]:
    """Positive and negative (query, track) distances of a labelled embedding set.

    A track is the group of embeddings of one (identity, camera). A query is one
    embedding (identity a, camera c) with ``query="crop"``, or the re-normalised mean
    of one track's embeddings (identity a, camera c; query expansion) with
    ``query="track"``. Its distance to a track of another camera c' ≠ c is the
    aggregate of the query's distances to the track's members; (query, track of a)
    is a positive pair, (query, track of b ≠ a) a negative one.

    Args:
        embeddings: (N, D) L2-normalised (only the crops the run would use).
        ids, cams: N identity and camera labels.
        aggregate: a name in `AGGREGATORS`.
        max_queries: use at most this many queries, drawn with `rng` (None: all).
        rng: random generator for the query sample (required when sampling).
        chunk: queries per distance block (memory: chunk × N floats).
        query: a name in `QUERIES`.

    Returns:
        (positive (P,), negative (Q,)) float64 distances.

    Raises:
        ReidDecisionError: shapes or labels disagree, an unknown query, or sampling
            without `rng`.
    """
    fn = aggregator(aggregate)
    if query not in QUERIES:
        raise ReidDecisionError(f"unknown query {query!r}; valid: {', '.join(QUERIES)}")
    e = np.asarray(embeddings, dtype=np.float64)
    ids_a = np.asarray(ids)
    cams_a = np.asarray(cams)
    if e.ndim != 2 or len(ids_a) != len(e) or len(cams_a) != len(e):
        raise ReidDecisionError(f"pair_distances: embeddings {e.shape}, {len(ids_a)} ids, "
                                f"{len(cams_a)} cameras")
    groups: dict[tuple, list[int]] = {}
    for i, (a, c) in enumerate(zip(ids_a.tolist(), cams_a.tolist(), strict=True)):
        groups.setdefault((a, c), []).append(i)
    # groups of one size are aggregated together: (queries, groups, size) blocks
    by_size: dict[int, list[tuple]] = {}
    for k, members in groups.items():
        by_size.setdefault(len(members), []).append((k, members))
    blocks = [(np.array([k[0] for k, _ in gs]), np.array([k[1] for k, _ in gs]),
               np.array([m for _, m in gs])) for _, gs in sorted(by_size.items())]
    if query == "crop":
        qv, q_ids, q_cams = e, ids_a, cams_a
    else:
        keys = list(groups)
        m = np.stack([e[groups[k]].mean(axis=0) for k in keys]) if keys else e[:0]
        qv = m / np.maximum(np.linalg.norm(m, axis=1, keepdims=True), 1e-12)
        q_ids = np.array([k[0] for k in keys])
        q_cams = np.array([k[1] for k in keys])
    queries = np.arange(len(qv))
    if max_queries is not None and len(queries) > max_queries:
        if rng is None:
            raise ReidDecisionError("pair_distances: sampling queries needs a random generator")
        queries = np.sort(rng.choice(len(qv), size=max_queries, replace=False))
    pos: list[np.ndarray] = []
    neg: list[np.ndarray] = []
    for s in range(0, len(queries), chunk):
        qi = queries[s:s + chunk]
        d = np.clip(1.0 - qv[qi] @ e.T, 0.0, 2.0) if query == "track" else \
            cosine_distances(e[qi], e)
        for gid, gcam, members in blocks:
            agg = fn(d[:, members])                       # (queries, groups)
            cross = gcam[None, :] != q_cams[qi][:, None]  # the VeRi cross-camera rule
            same = gid[None, :] == q_ids[qi][:, None]
            pos.append(agg[cross & same])
            neg.append(agg[cross & ~same])
    pos_a = np.concatenate(pos) if pos else np.empty(0)
    neg_a = np.concatenate(neg) if neg else np.empty(0)
    return pos_a, neg_a


def calibrate_threshold(embeddings: np.ndarray, ids: Sequence[int], cams: Sequence[int], *,
                        rule: str = "precision", target_precision: float = 0.99,
                        aggregate: str = "median", max_queries: int | None = 2000,
                        rng: np.random.Generator | None = None,
                        recipe: Recipe | None = None, max_far: float = 0.02) -> Calibration:
    """The track decision threshold from embeddings of TRAINING identities.

    `pair_distances` forms the (query, cross-camera track) pairs with the run's
    aggregator and query (`recipe`; None: ``Recipe(aggregate)``, the paper's single
    crop); the embeddings must be those of the crops the recipe keeps
    (`adequate_crops`). `threshold_from_pairs` picks the threshold by `rule`. The
    returned precision and recall are measured on those pairs (training identities),
    not on any test run; the recipe is recorded in the `Calibration`.

    Raises:
        ReidDecisionError: as `pair_distances` and `threshold_from_pairs`.
    """
    from dataclasses import replace

    recipe = recipe if recipe is not None else Recipe(aggregate)
    pos, neg = pair_distances(embeddings, ids, cams, recipe.aggregate, max_queries, rng,
                              query=recipe.query)
    cal = threshold_from_pairs(pos, neg, rule, target_precision, recipe.aggregate, max_far)
    return replace(cal, query=recipe.query, min_box_px=float(recipe.min_box_px),
                   border_px=None if recipe.border_px is None else float(recipe.border_px))
