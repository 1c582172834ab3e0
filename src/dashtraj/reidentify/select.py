"""Pick the target's tracks: appearance decision per track, then the spatio-temporal gate.

`select_target_tracks` is the whole re-identification step after embedding:

1. `decide_tracks`: aggregate each track's detection distances to the query and keep
   the tracks at or below the calibrated threshold (the appearance candidates);
2. `dashtraj.trajectory.gating.gate_tracks`: among the candidates keep the heaviest
   chain one vehicle could have driven on the lane graph, through the query's own
   track when it is a candidate (the anchor). Two tracks of one camera that show
   separate boxes in the same frames (`box_relations`) are two vehicles: never
   both kept, even where one of them is beyond the ReID range and has no sighting
   there to compare positions (an oncoming car passing the target, 3 m away across
   the road centre, matched on appearance while the target was 16 m ahead). Two
   that show overlapping boxes in the same frames are one vehicle seen twice,
   whatever their positions (a box of a car's lower half is localized metres from
   the whole car's).

3. `LookalikeRule` (optional): when the gate dropped a candidate that looks as much like
   the query as the target's own tracks do, another vehicle of the target's look is
   about, and a track the gate kept only across a long unseen stretch (more than
   ``max_gap_s`` from every other kept track linked to the anchor) may as well be that
   vehicle: it is dropped too.

Weights: a track's number of sightings (sampled at a fixed period, so: how long
it was seen) times ``1 + margin``, the appearance margin
``(threshold − distance) / threshold / 2`` clipped to [0, 0.5). The gate keeps the
consistent set that explains the most observation time; appearance breaks near
ties. (One per track was tried first: with exact look-alikes, several short
look-alike tracks then outvoted one long track of the target's; see the README's
look-alike figures.)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Hashable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from dashtraj.perception.detections import intersection_matrix
from dashtraj.reidentify.decision import ReidDecisionError, TrackDecision, decide_tracks
from dashtraj.roads import RoadMap
from dashtraj.trajectory.gating import GateConfig, gate_tracks
from dashtraj.trajectory.records import Sighting
from dashtraj.trajectory.watch import Watch

DEFAULT_GATE = GateConfig()
"""The gate `select_target_tracks` uses unless told otherwise."""


@dataclass(frozen=True, slots=True)
class LookalikeRule:
    """Distrust long unseen stretches once a look-alike has shown itself.

    Two identical cars (the same model and colour: ``--twins``) cannot be told apart by
    appearance, and the gate keeps a track of either wherever the target *could* have
    been. Between two sightings seconds apart that is a few metres of road; after half a
    minute unseen it is much of a town, where a look-alike is as likely as the target.
    So, when the gate has dropped a candidate whose aggregated distance to the query is
    at most ``distance_frac`` x the threshold (another vehicle, seen where the target was
    not, that looks like it), only the kept tracks linked to the anchor (the query's own
    track) by a chain of kept tracks, each at most ``max_gap_s`` from the next (time
    between their sightings; overlapping tracks are 0 apart), stay. Without such a
    candidate, or without an anchor, nothing changes.

    Chosen on the development look-alike runs (``dashtraj experiments --twins 3 --seeds
    5-9``; 57 / 5 true / false tracks kept by the gate) and the development runs without
    look-alikes (``--seeds 5-9``, 57 / 0), from the kept and dropped tracks' times and
    distances (2026-12-06): a dropped candidate within 0.4 / 0.5 / 0.6 x the threshold
    marked 6 / 8 / 9 of the 10 look-alike runs and 1 of the 10 others; with 0.6, chains
    of 20 / 25 / 30 / 35 s kept 46 / 52 / 56 / 57 true and 1 / 1 / 2 / 5 false tracks, and
    every true track of the runs without look-alikes (the one marked run lost none). It
    did not hold on the ten look-alike experiments (``--twins 3
    --seeds 0-4``, scored once): 56 / 9 true / false tracks became 50 / 8, so it is off by
    default (`dashtraj.reidentify.vision.LOOKALIKE`).

    Attributes:
        distance_frac: a dropped candidate this close to the query (x the threshold)
            shows a look-alike; 0 < distance_frac.
        max_gap_s: the longest unseen stretch a chain of kept tracks bridges then,
            seconds; > 0.
    """

    distance_frac: float = 0.6
    max_gap_s: float = 30.0

    def __post_init__(self) -> None:
        for name in ("distance_frac", "max_gap_s"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ReidDecisionError(f"LookalikeRule.{name} must be a finite number > 0, "
                                        f"got {v!r}")


def linked_to(anchor: Hashable, spans: Mapping[Hashable, tuple[float, float]],
              max_gap_s: float) -> set:
    """Keys of `spans` ((first, last) seconds) linked to `anchor` by a chain in which each
    step is at most `max_gap_s` from the next (0 where they overlap); the anchor itself."""
    linked, todo = {anchor}, [anchor]
    while todo:
        a0, a1 = spans[todo.pop()]
        for k, (b0, b1) in spans.items():
            if k not in linked and max(b0 - a1, a0 - b1, 0.0) <= max_gap_s:
                linked.add(k)
                todo.append(k)
    return linked


@dataclass(frozen=True, slots=True)
class Selection:
    """The outcome of `select_target_tracks`.

    Attributes:
        decisions: one `TrackDecision` per track with distances.
        candidates: keys of the tracks at or below the threshold (before the gate).
        accepted: keys kept by the gate, in time order (== candidates without a gate).
        gated_out: candidates the gate dropped (`unlinked` among them).
        lookalikes: dropped candidates that showed a look-alike (`LookalikeRule`).
        unlinked: tracks the gate kept and the `LookalikeRule` dropped.
    """

    decisions: tuple[TrackDecision, ...]
    candidates: tuple[Hashable, ...]
    accepted: tuple[Hashable, ...]
    gated_out: tuple[Hashable, ...]
    lookalikes: tuple[Hashable, ...] = ()
    unlinked: tuple[Hashable, ...] = ()


def select_target_tracks(road_map: RoadMap, distances: np.ndarray, keys: Sequence[Hashable],
                         sightings: Mapping[Hashable, Sequence[Sighting]], threshold: float, *,
                         aggregate: str = "median", anchor: Hashable | None = None,
                         gate: GateConfig | None = DEFAULT_GATE,
                         keep_anchor: bool = False, pin_anchor: bool = True,
                         apart: Collection[frozenset] = (),
                         together: Collection[frozenset] = (),
                         start_t: float | None = None, watch: Watch | None = None,
                         lookalike: LookalikeRule | None = None) -> Selection:
    """Decide and gate the target's tracks.

    Args:
        road_map: the map (CARLA world, metres).
        distances: (N,) cosine distances of N detections to the query.
        keys: N track keys, e.g. (observer_id, track_id).
        sightings: each candidate track's sightings (positions and times for the
            gate); a candidate without any cannot be placed on the map, and the
            gate drops it (as it drops one seen only before `start_t`).
        threshold: the calibrated threshold (`calibrate_threshold`).
        aggregate: a name in `AGGREGATORS`.
        anchor: key of the query's own track (kept through the gate when it is a
            candidate), or None.
        gate: `GateConfig`, or None for no gate (the paper's way).
        keep_anchor: the anchor is a candidate whatever its distance (the track the
            user pointed at is the target by definition; its aggregated distance to
            the query can exceed the threshold when the query crop is unlike the
            rest of its track).
        pin_anchor: the gate keeps the anchor whatever the other candidates say (the
            best consistent set *containing* it); False: the anchor is one candidate
            among the others (weighed like them), so a track that the tracker joined
            to other boxes after the query crop cannot pull true tracks out.
        apart: pairs of track keys (frozensets of two) known to be two vehicles
            (`box_relations`); the gate never keeps both.
        together: pairs of one camera's track keys seen as one vehicle
            (`box_relations`); the gate does not call them two vehicles for being
            localized apart at one moment (`GateConfig.same_camera_m`).
        start_t: the time of the target's first sighting (the query crop's, as
            ``calc_traj`` takes ``veh_t1``), seconds, or None. With a gate, a candidate
            whose sightings all come before it is not the target: the route is rebuilt
            from the first sighting on, and a vehicle seen only before the target's
            first sighting is another one (a look-alike met earlier; `gate_tracks`'
            rule).
        watch: a `dashtraj.trajectory.watch.Watch` for the gate (negative evidence:
            `gate_tracks`), or None.
        lookalike: a `LookalikeRule` after the gate, or None (none).

    Returns:
        `Selection`.

    Raises:
        ReidDecisionError, GatingError: as `decide_tracks` and `gate_tracks`.
    """
    decisions = decide_tracks(distances, keys, threshold, aggregate)
    cand = [d for d in decisions if d.target or (keep_anchor and d.key == anchor)]
    cand_keys = tuple(d.key for d in cand)
    if gate is None:
        return Selection(tuple(decisions), cand_keys, cand_keys, ())
    placed = [d for d in cand if len(sightings.get(d.key, ())) > 0]
    scale = threshold if threshold > 0 else 1.0
    weights = [len(sightings[d.key])
               * (1.0 + float(np.clip((threshold - d.distance) / scale / 2, 0.0, 0.499)))
               for d in placed]
    idx = {d.key: i for i, d in enumerate(placed)}

    def indices(pairs):
        return [tuple(idx[k] for k in pair) for pair in pairs
                if len(pair) == 2 and all(k in idx for k in pair)]

    res = gate_tracks(road_map, [sightings[d.key] for d in placed], weights=weights,
                      anchor=idx.get(anchor) if anchor is not None and pin_anchor else None,
                      config=gate, apart=indices(apart), together=indices(together),
                      start_t=start_t, watch=watch)
    accepted = tuple(placed[i].key for i in res.accepted)
    shown, unlinked = (), ()
    if lookalike is not None and anchor in accepted:
        gate_kept = set(accepted)
        shown = tuple(d.key for d in placed if d.key not in gate_kept
                      and d.distance <= lookalike.distance_frac * threshold)
        if shown:
            spans = {k: (min(s.t for s in sightings[k]), max(s.t for s in sightings[k]))
                     for k in accepted}
            linked = linked_to(anchor, spans, lookalike.max_gap_s)
            unlinked = tuple(k for k in accepted if k not in linked)
            accepted = tuple(k for k in accepted if k in linked)
    kept = set(accepted)
    out = tuple(k for k in cand_keys if k not in kept)
    return Selection(tuple(decisions), cand_keys, accepted, out, shown, unlinked)


def tracks_of(sightings: Sequence[Sighting]) -> dict[tuple[int, int | None], list[Sighting]]:
    """Group sightings by (observer_id, track_id), each group in time order.

    The `sightings` argument of `select_target_tracks` from a flat list, e.g. a
    sightings DB's ``SightingsDB.sightings(max_distance_m=15, sample_s=0.5)``.
    """
    out: dict[tuple[int, int | None], list[Sighting]] = {}
    for s in sorted(sightings, key=lambda s: (s.t, s.observer_id)):
        out.setdefault((s.observer_id, s.track_id), []).append(s)
    return out


@dataclass(frozen=True, slots=True)
class BoxRelations:
    """What one camera's boxes say about pairs of its tracks (`box_relations`).

    Attributes:
        apart: pairs seen as two vehicles (separate boxes in the same frames).
        together: pairs seen as one vehicle twice (overlapping boxes in the same frames).
    """

    apart: frozenset[frozenset]
    together: frozenset[frozenset]


def box_relations(detections, spans: Mapping[Hashable, tuple[float, float]] | None = None,
                  min_frames: int = 2, max_overlap: float = 0.1,
                  key: Callable[[object], Hashable] | None = None) -> BoxRelations:
    """Pairs of one camera's tracks that its pixels show as two vehicles, or as one.

    In a frame where two tracks of one observer both have a box, the boxes are
    *separate* when they overlap by at most `max_overlap` of the smaller box (their
    intersection over its area), and *overlapping* otherwise. Two tracks are:

    - **apart** (two vehicles) when their boxes were separate in `min_frames` frames
      or more and never overlapping: one frame alone could be a tracker's slip onto
      the scenery, and two tracks that did share a box's pixels once may be two
      tracks on one vehicle, one of which strayed to a neighbour for a while;
    - **together** (one vehicle seen twice: a second box of another orientation
      class, a box of its lower half or of the part a nearer car leaves visible)
      when their boxes overlapped in `min_frames` frames or more and were never
      separate. Such a second box is localized from other pixels, metres away from
      the first (a cut box's height says little), so positions alone would call the
      two tracks two vehicles.

    With `spans`, only frames inside both tracks' spans count: a tracker can carry a
    track onto another vehicle after it lost its own (or start it there before), and
    only the part of a track that the gate weighs (its sightings) says which vehicle
    the track is.

    Args:
        detections: rows with observer_id, frame, t, track_id and the box x0, y0,
            x1, y1 (`SightingsDB.detections()`); rows without a track are ignored.
        spans: (first t, last t) of each track's sightings, by key; a track without
            one is in no pair. None: every frame counts.
        min_frames: frames needed, >= 1.
        max_overlap: the largest intersection over the smaller box's area that
            still counts as separate, in [0, 1).
        key: a detection's track key; None: (observer_id, track_id). A pipeline that
            cuts tracks into parts (`vision.split_tracks`) passes its own.

    Returns:
        `BoxRelations` of frozensets {(observer_id, track_id_a), (observer_id,
        track_id_b)}: the keys of `tracks_of` and of the vision pipeline (with `key`,
        pairs of its keys).
    """
    if min_frames < 1 or not 0 <= max_overlap < 1:
        raise ValueError(f"box_relations: min_frames >= 1 and 0 <= max_overlap < 1, got "
                         f"{min_frames!r}, {max_overlap!r}")

    key_of = key if key is not None else (lambda d: (d.observer_id, d.track_id))

    def inside(d) -> bool:
        if spans is None:
            return True
        span = spans.get(key_of(d))
        return span is not None and span[0] <= d.t <= span[1]

    by_frame: dict[tuple[int, int], list] = {}
    for d in detections:
        if d.track_id is not None and inside(d):
            by_frame.setdefault((d.observer_id, d.frame), []).append(d)
    separate: dict[frozenset, int] = {}
    overlapping: dict[frozenset, int] = {}
    for ds in by_frame.values():
        ks = [key_of(d) for d in ds]
        if len(set(ks)) < 2:
            continue
        b = np.array([[d.x0, d.y0, d.x1, d.y1] for d in ds], dtype=np.float64)
        area = np.clip(b[:, 2] - b[:, 0], 0, None) * np.clip(b[:, 3] - b[:, 1], 0, None)
        sep = intersection_matrix(b, b) <= max_overlap * np.minimum(area[:, None], area[None, :])
        seen_sep, seen_over = set(), set()
        for i in range(len(ds)):
            for j in range(i + 1, len(ds)):
                if ks[i] != ks[j]:
                    pair = frozenset({ks[i], ks[j]})
                    (seen_sep if sep[i, j] else seen_over).add(pair)
        for seen, count in ((seen_sep, separate), (seen_over, overlapping)):
            for pair in seen:  # once per frame, however many boxes a track has in it
                count[pair] = count.get(pair, 0) + 1
    return BoxRelations(
        frozenset(p for p, n in separate.items() if n >= min_frames and p not in overlapping),
        frozenset(p for p, n in overlapping.items() if n >= min_frames and p not in separate))


def query_detection(db, vehicle_id: int, max_distance_m: float = 15.0, usable=None,
                    detections=None):
    """The query of re-identification: the vehicle's first detection with a crop, within
    `max_distance_m` (estimated) of a camera, as ``calc_traj`` takes ``veh_t1.image``.

    Picking it needs the vehicle's identity (the user points at the car to follow);
    the truth ids of the DB stand for that choice.

    Args:
        db: an open `dashtraj.store.SightingsDB`.
        vehicle_id: the renderer's vehicle id of the target.
        max_distance_m: the ReID range, metres.
        usable: None, or ``usable(detection) -> bool``: the first detection it accepts
            (e.g. a crop the decision recipe uses: large enough, not cut by the
            frame), falling back to the first of all when it accepts none.
        detections: the detections to choose from (e.g. those scored high enough), or
            None: every detection of `db`.

    Returns:
        The `DetectionRow` (its (observer_id, track_id) is the gate's anchor), or None
        when no such detection has a crop.
    """
    return _first_crop(db, lambda d: d.truth_vehicle_id == vehicle_id, max_distance_m, usable,
                       detections)


def track_query_detection(db, key: tuple[int, int], max_distance_m: float = 15.0,
                          usable=None, detections=None):
    """The query when the user points at a track instead of a vehicle (a drive has no
    truth): the first detection of track ``key`` = (observer_id, track_id) with a crop,
    within `max_distance_m`, preferring what ``usable`` accepts (as `query_detection`).
    None when the track has no such detection."""
    return _first_crop(db, lambda d: (d.observer_id, d.track_id) == tuple(key),
                       max_distance_m, usable, detections)


def _first_crop(db, pick, max_distance_m: float, usable, detections):
    with_crop = {(c.observer_id, c.frame, c.idx) for c in db.crops()}
    mine = sorted((d for d in (db.detections() if detections is None else detections)
                   if pick(d) and d.distance_m <= max_distance_m
                   and (d.observer_id, d.frame, d.idx) in with_crop),
                  key=lambda d: (d.t, d.observer_id, d.idx))
    if usable is not None:
        good = [d for d in mine if usable(d)]
        if good:
            return good[0]
    return mine[0] if mine else None
