"""Pick the target's tracks: appearance decision per track, then the spatio-temporal gate.

`select_target_tracks` is the whole re-identification step after embedding:

1. `decide_tracks`: aggregate each track's detection distances to the query and keep
   the tracks at or below the calibrated threshold (the appearance candidates);
2. `dashtraj.trajectory.gating.gate_tracks`: among the candidates keep the heaviest
   chain one vehicle could have driven on the lane graph, through the query's own
   track when it is a candidate (the anchor).

Weights: a track's number of sightings (sampled at a fixed period, so: how long
it was seen) times ``1 + margin``, the appearance margin
``(threshold − distance) / threshold / 2`` clipped to [0, 0.5). The gate keeps the
consistent set that explains the most observation time; appearance breaks near
ties. (One per track was tried first: with exact look-alikes, several short
look-alike tracks then outvoted one long track of the target's; see the README's
look-alike figures.)
"""

from __future__ import annotations

from collections.abc import Hashable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from dashtraj.reidentify.decision import TrackDecision, decide_tracks
from dashtraj.roads import RoadMap
from dashtraj.trajectory.gating import GateConfig, gate_tracks
from dashtraj.trajectory.records import Sighting

DEFAULT_GATE = GateConfig()
"""The gate `select_target_tracks` uses unless told otherwise."""


@dataclass(frozen=True, slots=True)
class Selection:
    """The outcome of `select_target_tracks`.

    Attributes:
        decisions: one `TrackDecision` per track with distances.
        candidates: keys of the tracks at or below the threshold (before the gate).
        accepted: keys kept by the gate, in time order (== candidates without a gate).
        gated_out: candidates the gate dropped.
    """

    decisions: tuple[TrackDecision, ...]
    candidates: tuple[Hashable, ...]
    accepted: tuple[Hashable, ...]
    gated_out: tuple[Hashable, ...]


def select_target_tracks(road_map: RoadMap, distances: np.ndarray, keys: Sequence[Hashable],
                         sightings: Mapping[Hashable, Sequence[Sighting]], threshold: float, *,
                         aggregate: str = "median", anchor: Hashable | None = None,
                         gate: GateConfig | None = DEFAULT_GATE,
                         keep_anchor: bool = False, pin_anchor: bool = True) -> Selection:
    """Decide and gate the target's tracks.

    Args:
        road_map: the map (CARLA world, metres).
        distances: (N,) cosine distances of N detections to the query.
        keys: N track keys, e.g. (observer_id, track_id).
        sightings: each candidate track's sightings (positions and times for the
            gate); a candidate without any cannot be placed on the map, and the
            gate drops it.
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
    res = gate_tracks(road_map, [sightings[d.key] for d in placed], weights=weights,
                      anchor=idx.get(anchor) if anchor is not None and pin_anchor else None,
                      config=gate)
    accepted = tuple(placed[i].key for i in res.accepted)
    out = tuple(k for k in cand_keys if k not in set(accepted))
    return Selection(tuple(decisions), cand_keys, accepted, out)


def tracks_of(sightings: Sequence[Sighting]) -> dict[tuple[int, int | None], list[Sighting]]:
    """Group sightings by (observer_id, track_id), each group in time order.

    The `sightings` argument of `select_target_tracks` from a flat list, e.g. a
    sightings DB's ``SightingsDB.sightings(max_distance_m=15, sample_s=0.5)``.
    """
    out: dict[tuple[int, int | None], list[Sighting]] = {}
    for s in sorted(sightings, key=lambda s: (s.t, s.observer_id)):
        out.setdefault((s.observer_id, s.track_id), []).append(s)
    return out


def query_detection(db, vehicle_id: int, max_distance_m: float = 15.0, usable=None):
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

    Returns:
        The `DetectionRow` (its (observer_id, track_id) is the gate's anchor), or None
        when no such detection has a crop.
    """
    with_crop = {(c.observer_id, c.frame, c.idx) for c in db.crops()}
    mine = sorted((d for d in db.detections()
                   if d.truth_vehicle_id == vehicle_id and d.distance_m <= max_distance_m
                   and (d.observer_id, d.frame, d.idx) in with_crop),
                  key=lambda d: (d.t, d.observer_id, d.idx))
    if usable is not None:
        good = [d for d in mine if usable(d)]
        if good:
            return good[0]
    return mine[0] if mine else None
