"""Precision and recall of the accepted target tracks against the truth.

A track is the unit of the decision: (observer_id, track_id). Its truth is the
renderer's vehicle id most of its detections belong to (the sightings DB's
``tracks.truth_vehicle_id``; evaluation only). Against the target's vehicle id:

- a true match is an accepted track whose truth is the target,
- a false match is an accepted track whose truth is another vehicle (or unknown),
- a miss is a track whose truth is the target that was not accepted.

precision = TP / (TP + FP) and recall = TP / (TP + FN), each None when its
denominator is 0 (nothing accepted; the target never tracked). Over several
experiments the counts are summed first (`pool`): "over all accepted tracks", as
the issue's targets are stated, so a run with many tracks weighs more.

`sighting_score` counts the same per sighting instead of per track: of the sightings
the accepted tracks hand to the reconstruction, how many show the target, and of all
the sightings that show it, how many were handed over. A track of one stray box and a
track of sixty count alike per track; per sighting they weigh what they bring to the
route.
"""

from __future__ import annotations

from collections.abc import Hashable, Iterable, Mapping
from dataclasses import dataclass

from dashtraj.errors import DashtrajError


class ReidScoreError(DashtrajError, ValueError):
    """An accepted track that the truth does not know."""


@dataclass(frozen=True, slots=True)
class ReidScore:
    """Counts and rates of one decision against the truth (see the module docstring)."""

    true_matches: int
    false_matches: int
    misses: int

    @property
    def precision(self) -> float | None:
        n = self.true_matches + self.false_matches
        return self.true_matches / n if n else None

    @property
    def recall(self) -> float | None:
        n = self.true_matches + self.misses
        return self.true_matches / n if n else None

    def to_dict(self) -> dict:
        return {"reid_precision": self.precision, "reid_recall": self.recall,
                "reid_true_matches": self.true_matches,
                "reid_false_matches": self.false_matches, "reid_misses": self.misses}

    def sightings_dict(self) -> dict:
        """The counts and rates as sightings (`sighting_score`)."""
        return {"reid_sighting_precision": self.precision,
                "reid_sighting_recall": self.recall,
                "reid_sightings_true": self.true_matches,
                "reid_sightings_false": self.false_matches,
                "reid_sightings_missed": self.misses}


def reid_score(accepted: Iterable[Hashable], truth: Mapping[Hashable, int | None],
               target_vehicle_id: int) -> ReidScore:
    """Score accepted tracks against the truth.

    Args:
        accepted: keys of the tracks decided "target", e.g. (observer_id, track_id).
        truth: every candidate track's key → its true vehicle id (None: unknown,
            which counts as not the target).
        target_vehicle_id: the target's vehicle id in the recording.

    Returns:
        `ReidScore`.

    Raises:
        ReidScoreError: an accepted key is not in `truth`.

    Example:
        >>> s = reid_score([(1, 4), (2, 7)], {(1, 4): 0, (2, 7): 5, (3, 1): 0}, 0)
        >>> s.precision, s.recall
        (0.5, 0.5)
    """
    acc = set(accepted)
    unknown = [k for k in acc if k not in truth]
    if unknown:
        raise ReidScoreError(f"accepted track {sorted(unknown, key=repr)[0]!r} is not among the "
                             "tracks the truth covers")
    tp = sum(1 for k in acc if truth[k] == target_vehicle_id)
    fp = len(acc) - tp
    fn = sum(1 for k, v in truth.items() if v == target_vehicle_id and k not in acc)
    return ReidScore(tp, fp, fn)


def sighting_score(shown: Iterable[tuple[Hashable, int | None]],
                   accepted: Iterable[Hashable], target_vehicle_id: int) -> ReidScore:
    """Score accepted tracks per sighting (module docstring).

    Args:
        shown: (track key, the vehicle id the sighting shows, None for none) of every
            sighting of every track.
        accepted: keys of the tracks decided "target".
        target_vehicle_id: the target's vehicle id in the recording.

    Returns:
        `ReidScore` of sightings: true = accepted and showing the target, false =
        accepted and not, misses = showing the target and not accepted.

    Example:
        >>> s = sighting_score([("a", 0), ("a", 0), ("a", None), ("b", 0)], ["a"], 0)
        >>> (s.true_matches, s.false_matches, s.misses)
        (2, 1, 1)
    """
    acc = set(accepted)
    tp = fp = fn = 0
    for k, v in shown:
        if k in acc:
            tp += v == target_vehicle_id
            fp += v != target_vehicle_id
        else:
            fn += v == target_vehicle_id
    return ReidScore(tp, fp, fn)


def pool(scores: Iterable[ReidScore]) -> ReidScore:
    """Sum the counts of several experiments (micro average)."""
    tp = fp = fn = 0
    for s in scores:
        tp += s.true_matches
        fp += s.false_matches
        fn += s.misses
    return ReidScore(tp, fp, fn)


def truth_of_tracks(db, max_distance_m: float | None = None) -> dict[tuple[int, int], int | None]:
    """(observer_id, track_id) → truth vehicle id of the tracks in a sightings DB.

    Args:
        db: an open `dashtraj.store.SightingsDB`.
        max_distance_m: only tracks with a detection estimated this close (the ReID
            range: the gallery holds crops of those only), or None for all.
    """
    if max_distance_m is None:
        return {(t.observer_id, t.track_id): t.truth_vehicle_id for t in db.tracks()}
    near = {(d.observer_id, d.track_id) for d in db.detections()
            if d.track_id is not None and d.distance_m <= max_distance_m}
    return {(t.observer_id, t.track_id): t.truth_vehicle_id for t in db.tracks()
            if (t.observer_id, t.track_id) in near}
