"""Decision + gate on Town01: an exact look-alike passes the appearance threshold, the
gate removes it (road 12 vs the parallel road 4, see tests/trajectory/test_gating.py)."""

from __future__ import annotations

import numpy as np
import pytest

from dashtraj.reidentify.decision import ReidDecisionError
from dashtraj.reidentify.scoring import reid_score
from dashtraj.reidentify.select import (
    LookalikeRule,
    box_relations,
    linked_to,
    select_target_tracks,
)
from dashtraj.store.db import DetectionRow
from gating_helpers import drive, sight


def test_gate_restores_precision_with_a_twin(town01):
    tracks = {
        (1, 1): drive(town01, 0.0, 2.0, 12, 20.0, obs=1, track=1),       # the target
        (2, 5): drive(town01, 10.0, 12.0, 12, 120.0, obs=2, track=5),    # the target
        (3, 2): drive(town01, 9.0, 11.0, 4, 120.0, obs=3, track=2),      # its twin, elsewhere
        (4, 7): drive(town01, 18.0, 20.0, 12, 200.0, obs=4, track=7),    # the target
        (4, 8): drive(town01, 18.0, 19.0, 12, 180.0, obs=4, track=8),    # another car
    }
    truth = {(1, 1): 0, (2, 5): 0, (3, 2): 9, (4, 7): 0, (4, 8): 3}
    # three detections per track; the twin looks exactly like the target
    per_track = {(1, 1): 0.2, (2, 5): 0.25, (3, 2): 0.2, (4, 7): 0.3, (4, 8): 0.8}
    keys = [k for k in per_track for _ in range(3)]
    d = np.array([per_track[k] + dd for k in per_track for dd in (-0.05, 0.0, 0.3)])
    paper = select_target_tracks(town01, d, keys, tracks, 0.5, gate=None)
    assert set(paper.candidates) == {(1, 1), (2, 5), (3, 2), (4, 7)}
    s = reid_score(paper.accepted, truth, 0)
    assert (s.precision, s.recall) == (0.75, 1.0)
    gated = select_target_tracks(town01, d, keys, tracks, 0.5, anchor=(1, 1))
    assert gated.accepted == ((1, 1), (2, 5), (4, 7)) and gated.gated_out == ((3, 2),)
    s = reid_score(gated.accepted, truth, 0)
    assert (s.precision, s.recall) == (1.0, 1.0)
    # medians: 0.2 + 0 for the target's first track, 0.8 for the other car
    by_key = {x.key: x for x in gated.decisions}
    assert by_key[(1, 1)].distance == 0.2 and not by_key[(4, 8)].target


def test_an_unpinned_anchor_cannot_pull_true_tracks_out(town01):
    """The query's track held the target for its first second, then the tracker joined
    boxes of something on the parallel street to it (road 6, while the target drove on
    road 12). Pinned, the gate keeps that track and drops the target's other tracks, which
    cannot coexist with its second half; weighed like any candidate, it is the one dropped."""
    anchor = (drive(town01, 0.0, 1.0, 12, 20.0, obs=1, track=1)
              + drive(town01, 1.5, 4.0, 6, 100.0, obs=1, track=1))
    tracks = {
        (1, 1): anchor,
        (2, 5): drive(town01, 2.0, 4.0, 12, 40.0, obs=2, track=5),    # the target
        (3, 2): drive(town01, 5.0, 7.0, 12, 70.0, obs=3, track=2),    # the target
        (4, 7): drive(town01, 8.0, 10.0, 12, 100.0, obs=4, track=7),  # the target
    }
    truth = {(1, 1): None, (2, 5): 0, (3, 2): 0, (4, 7): 0}
    keys = [k for k in tracks for _ in range(3)]
    d = np.array([0.1, 0.12, 0.14] * len(tracks))
    pinned = select_target_tracks(town01, d, keys, tracks, 0.5, anchor=(1, 1), keep_anchor=True)
    free = select_target_tracks(town01, d, keys, tracks, 0.5, anchor=(1, 1), keep_anchor=True,
                                pin_anchor=False)
    assert pinned.accepted == ((1, 1),)
    assert free.accepted == ((2, 5), (3, 2), (4, 7)) and free.gated_out == ((1, 1),)
    assert reid_score(free.accepted, truth, 0).precision == 1.0
    assert reid_score(pinned.accepted, truth, 0).recall < 1.0


def test_a_look_alike_seen_only_before_the_query_is_not_the_target(town01):
    """The query is the target's first sighting (``calc_traj``'s ``veh_t1``): a track of
    the same look that ended before it is another vehicle, however reachable its
    place was; one still seen at the query's time stays a candidate for the gate."""
    tracks = {
        (2, 3): drive(town01, 0.0, 2.0, 12, 0.0, obs=2, track=3),      # a twin, earlier
        (1, 1): drive(town01, 5.0, 7.0, 12, 60.0, obs=1, track=1),     # the query's track
        (3, 4): drive(town01, 10.0, 12.0, 12, 110.0, obs=3, track=4),  # the target
    }
    keys = [k for k in tracks for _ in range(3)]
    d = np.array([0.1, 0.12, 0.14] * len(tracks))
    # the twin drove the target's road 40 m short of where the query saw it, 3 s before:
    # reachable
    free = select_target_tracks(town01, d, keys, tracks, 0.5, anchor=(1, 1))
    assert free.accepted == ((2, 3), (1, 1), (3, 4))
    first = select_target_tracks(town01, d, keys, tracks, 0.5, anchor=(1, 1), start_t=5.0)
    assert first.accepted == ((1, 1), (3, 4)) and first.gated_out == ((2, 3),)
    # a track that ends at or after the query's time is judged by the gate alone
    late = select_target_tracks(town01, d, keys, tracks, 0.5, anchor=(1, 1), start_t=2.0)
    assert late.accepted == free.accepted
    # no gate, no rule: the paper's way accepts every match
    assert select_target_tracks(town01, d, keys, tracks, 0.5, gate=None,
                                start_t=5.0).accepted == tuple(tracks)



def test_a_look_alike_in_view_stops_long_unseen_stretches(town01):
    """Once the gate has dropped a candidate that looks like the query (a twin on the
    parallel road while the target was on road 12), a track kept only across more than
    `max_gap_s` unseen is no longer trusted; without the twin, or across short gaps,
    nothing changes."""
    target = {
        (1, 1): drive(town01, 0.0, 2.0, 12, 20.0, obs=1, track=1),     # the query's track
        (2, 5): drive(town01, 10.0, 12.0, 12, 120.0, obs=2, track=5),  # 8 s later
        (4, 7): drive(town01, 50.0, 52.0, 12, 180.0, obs=4, track=7),  # 38 s unseen
    }
    twin = {(3, 2): drive(town01, 9.0, 11.0, 4, 120.0, obs=3, track=2)}
    rule = LookalikeRule(distance_frac=0.6, max_gap_s=30.0)

    def select(tracks, dist, **kw):
        keys = [k for k in tracks for _ in range(3)]
        d = np.array([dist.get(k, 0.1) + dd for k in tracks for dd in (0.0, 0.01, 0.02)])
        return select_target_tracks(town01, d, keys, tracks, 0.5, anchor=(1, 1), **kw)

    both = {**target, **twin}
    plain = select(both, {})
    assert plain.accepted == ((1, 1), (2, 5), (4, 7)) and plain.gated_out == ((3, 2),)
    ruled = select(both, {}, lookalike=rule)
    assert ruled.lookalikes == ((3, 2),) and ruled.unlinked == ((4, 7),)
    assert ruled.accepted == ((1, 1), (2, 5)) and set(ruled.gated_out) == {(3, 2), (4, 7)}
    # a track 20 s on links the far one (two gaps of 19 s)
    mid = {(5, 9): drive(town01, 31.0, 31.0, 12, 150.0, obs=5, track=9)}
    assert select({**both, **mid}, {}, lookalike=rule).accepted == \
        ((1, 1), (2, 5), (5, 9), (4, 7))
    # no look-alike dropped: no change; one that looks less like the query (0.35 > 0.3):
    # no change; a longer allowed gap: no change
    assert select(target, {}, lookalike=rule).accepted == plain.accepted
    assert select(both, {(3, 2): 0.35}, lookalike=rule).unlinked == ()
    assert select(both, {}, lookalike=LookalikeRule(0.6, 40.0)).accepted == plain.accepted
    with pytest.raises(ReidDecisionError, match="max_gap_s"):
        LookalikeRule(max_gap_s=0.0)
    with pytest.raises(ReidDecisionError, match="distance_frac"):
        LookalikeRule(distance_frac=float("nan"))


def test_linked_to_follows_chains_both_ways_in_time():
    spans = {"a": (10.0, 12.0), "b": (0.0, 5.0), "c": (20.0, 21.0), "d": (40.0, 41.0),
             "e": (11.0, 50.0)}
    assert linked_to("a", {k: spans[k] for k in "abcd"}, 8.0) == {"a", "b", "c"}
    assert linked_to("a", {k: spans[k] for k in "abcd"}, 5.0) == {"a", "b"}
    assert linked_to("a", spans, 1.0) == {"a", "c", "d", "e"}  # e overlaps a, c and d

def _row(obs, frame, track, box, t=None):
    return DetectionRow(observer_id=obs, frame=frame, idx=0, t=frame * 0.2 if t is None else t,
                        track_id=track, x0=box[0], y0=box[1], x1=box[2], y1=box[3],
                        score=0.8, class_id=0, vehicle_class="car", orientation="back",
                        distance_m=10.0, bearing_deg=0.0, x=0.0, y=0.0, z=0.0, road_id=None,
                        section_id=None, lane_id=None, s=None, lateral_m=None,
                        truth_vehicle_id=None, depicted_vehicle_id=None)


def test_box_relations_two_vehicles_from_separate_boxes():
    """Real boxes of the town01 seed 0 run (shipped detector, score >= 0.45): observer 3
    follows the target (track 2, 293-334 px wide, 16.5 m ahead) while an oncoming car
    (track 25) passes to its left in frames 318-322; separate boxes in three frames."""
    target = {318: (293.3, 182.4, 333.9, 214.2), 319: (292.9, 181.6, 334.6, 216.6),
              320: (293.1, 182.1, 334.7, 216.0), 321: (293.3, 182.0, 333.9, 214.6)}
    oncoming = {318: (231.7, 181.4, 270.5, 215.6), 319: (212.0, 182.1, 261.1, 222.4),
                320: (187.2, 183.4, 252.7, 225.2)}
    rows = ([_row(3, f, 2, b) for f, b in target.items()]
            + [_row(3, f, 25, b) for f, b in oncoming.items()]
            + [_row(1, 318, 4, oncoming[318]), _row(3, 318, None, (0, 0, 5, 5))])
    pair = frozenset({(3, 2), (3, 25)})
    rel = box_relations(rows)
    assert (rel.apart, rel.together) == ({pair}, set())
    # one frame is not enough (a tracker's slip); three are when asked for
    assert box_relations(rows, min_frames=4).apart == set()
    # only frames inside both tracks' sighting spans count
    spans = {(3, 2): (0.0, 100.0), (3, 25): (63.8, 64.0)}  # frames 319 and 320 only
    assert box_relations(rows, spans).apart == {pair}
    assert box_relations(rows, {(3, 2): (0.0, 100.0), (3, 25): (64.0, 64.0)}).apart == set()
    assert box_relations(rows, {(3, 2): (0.0, 100.0)}).apart == set()
    # a frame in which the two tracks' boxes overlap (a second box on one vehicle, one
    # track having strayed to a neighbour elsewhere): neither two vehicles nor one
    mixed = box_relations([*rows, _row(3, 321, 25, (300.0, 185.0, 330.0, 214.0))])
    assert (mixed.apart, mixed.together) == (set(), set())
    # a small overlap (a neighbour's mirror inside the box) still counts as separate
    touching = [_row(3, f, 9, (b[0] - 38.0, b[1], b[0] + 2.0, b[3])) for f, b in target.items()]
    assert box_relations([*rows[:4], *touching]).apart == {frozenset({(3, 2), (3, 9)})}
    with pytest.raises(ValueError, match="min_frames"):
        box_relations(rows, min_frames=0)


def test_seen_spans_let_box_relations_see_a_track_just_beyond_the_range():
    """The look-alike case of the town01 seed 4 run with twins: observer 3 follows the
    target (track 71) 16-17 m ahead, just beyond the 15 m of the sightings, while a twin
    (track 72) passes it within 15 m; the target's sightings start 2.6 s after the twin's
    end. Over the sightings' spans the two are never seen at once; widened over the
    detections out to 20 m (`seen_spans`) they are two vehicles."""
    import dataclasses

    from dashtraj.reidentify.vision import seen_spans

    def at(obs, frame, track, box, dist):
        return dataclasses.replace(_row(obs, frame, track, box), distance_m=dist)

    target = [at(3, f, 71, (300.0, 180.0, 350.0, 222.0), 16.5) for f in range(255, 278)]
    target += [at(3, f, 71, (290.0, 170.0, 350.0, 225.0), 14.5) for f in range(278, 300)]
    twin = [at(3, f, 72, (160.0, 175.0, 230.0, 230.0), 12.0) for f in range(258, 266)]
    far = [at(3, f, 71, (305.0, 185.0, 345.0, 220.0), 31.0) for f in range(245, 255)]
    rows = [*far, *target, *twin]
    spans = {(3, 71): (278 * 0.2, 299 * 0.2), (3, 72): (258 * 0.2, 265 * 0.2)}
    assert box_relations(rows, spans).apart == set()

    def key(d):
        return d.observer_id, d.track_id

    wide = seen_spans(rows, spans, key, 20.0)
    # back over the detections at 16.5 m, not over those at 31 m
    assert wide[(3, 71)] == pytest.approx((255 * 0.2, 299 * 0.2))
    assert wide[(3, 72)] == spans[(3, 72)]
    assert box_relations(rows, wide).apart == {frozenset({(3, 71), (3, 72)})}
    # a gap longer than max_gap_s stops the widening
    gappy = [d for d in rows if not 270 <= d.frame < 277]
    assert seen_spans(gappy, spans, key, 20.0)[(3, 71)] == pytest.approx((277 * 0.2,
                                                                         299 * 0.2))
    assert seen_spans(rows, spans, key, 40.0)[(3, 71)] == pytest.approx((245 * 0.2,
                                                                        299 * 0.2))
    assert seen_spans(rows, spans, key, 15.0) == spans


def test_box_relations_one_vehicle_from_overlapping_boxes():
    """Real boxes of the town10 seed 9 development run: observer 3 follows the target, a
    motorcycle (track 75, its whole box) and the detector also boxes its rider's upper
    part (track 134, inside track 75's box), localized 3-12 m from it."""
    whole = {1216: (322.0, 184.0, 340.0, 247.0), 1220: (322.0, 183.0, 342.0, 248.0)}
    part = {1216: (323.0, 181.0, 332.0, 201.0), 1220: (321.0, 182.0, 334.0, 203.0)}
    rows = [_row(3, f, 75, b) for f, b in whole.items()] + \
        [_row(3, f, 134, b) for f, b in part.items()]
    rel = box_relations(rows)
    assert (rel.apart, rel.together) == (set(), {frozenset({(3, 75), (3, 134)})})
    assert box_relations(rows, min_frames=3).together == set()
    # once separate (the second track on another vehicle for a frame): not one vehicle
    rel = box_relations([*rows, _row(3, 1224, 75, (200.0, 180.0, 230.0, 240.0)),
                         _row(3, 1224, 134, (321.0, 181.0, 342.0, 245.0))])
    assert (rel.apart, rel.together) == (set(), set())


def test_select_never_keeps_two_tracks_seen_apart(town01):
    # by positions another car of observer 1 (track 2) could be the target; the pixels
    # said two vehicles
    target = (drive(town01, 0.0, 2.0, 12, 20.0, obs=1, track=1)
              + drive(town01, 6.0, 8.0, 12, 80.0, obs=1, track=1))
    oncoming = drive(town01, 4.0, 4.5, 12, 63.0, obs=1, track=2)
    tracks = {(1, 1): target, (1, 2): oncoming}
    keys = [(1, 1)] * 3 + [(1, 2)] * 3
    d = np.array([0.1, 0.1, 0.1, 0.2, 0.2, 0.2])
    both = select_target_tracks(town01, d, keys, tracks, 0.5, anchor=(1, 1))
    assert both.accepted == ((1, 1), (1, 2))
    one = select_target_tracks(town01, d, keys, tracks, 0.5, anchor=(1, 1),
                               apart={frozenset({(1, 1), (1, 2)}), frozenset({(1, 2), (7, 7)})})
    assert one.accepted == ((1, 1),) and one.gated_out == ((1, 2),)

    # seen together in the pixels, the camera's two tracks are one vehicle, whatever the
    # sightings' positions (the second track's boxes localized 4 m ahead of the first's)
    ahead = [sight(town01, t, 12, 20.0 + 10.0 * t + 4.0, obs=1, track=3) for t in (2.0, 2.5)]
    tracks = {(1, 1): target, (1, 3): ahead}
    keys = [(1, 1)] * 3 + [(1, 3)] * 3
    assert select_target_tracks(town01, d, keys, tracks, 0.5, anchor=(1, 1)).accepted == \
        ((1, 1),)
    joined = select_target_tracks(town01, d, keys, tracks, 0.5, anchor=(1, 1),
                                  together={frozenset({(1, 1), (1, 3)})})
    assert joined.accepted == ((1, 1), (1, 3))


def test_the_vision_gate_allows_less_slack_than_the_oracles(town01):
    """`target_from_db`'s gate takes 5 m of slack (perceive's positions are off by about
    a metre), the default 20 m (the oracle's paper noise): a second observer's sighting
    15 m farther along the lane 0.5 s later (15 m/s allows 7.5 m) is the same car for the
    default gate only."""
    from dashtraj.reidentify.vision import VISION_GATE
    from dashtraj.trajectory.gating import GateConfig, reachable

    a = sight(town01, 10.0, 12, 100.0, obs=1)
    for ds, default, vision in ((12.0, True, True), (15.0, True, False), (22.0, True, False),
                                (28.0, False, False)):
        b = sight(town01, 10.5, 12, 100.0 + ds, obs=2)
        assert reachable(town01, a, b, GateConfig()) is default
        assert reachable(town01, a, b, VISION_GATE) is vision
    assert VISION_GATE.slack_m == 5.0 and GateConfig().slack_m == 20.0


def test_the_vision_gate_reads_a_crawling_cars_way(town01):
    """A look-alike crawling in a queue (5 m in 5 s along road 12's lane -1, driving +x),
    seen by one camera until it pulls away; 2.5 s later the same camera sees the target
    6 m behind where the look-alike was last seen. One car would have backed up 6 m. The
    oracle's gate (a way shown by 8 m within 3 s) gives the crawler no way, so the
    opposite lane is one of its readings, on which the target's sighting lies ahead: one
    car. `target_from_db`'s gate reads its way from 3 m within 5 s: two vehicles; 4 m
    behind is still localization slack (5 m)."""
    from dataclasses import replace

    from dashtraj.reidentify.vision import VISION_GATE
    from dashtraj.trajectory.gating import GateConfig, gate_tracks

    crawler = [sight(town01, 60.0 + 0.5 * i, 12, 100.0 + 0.5 * i, obs=4, track=51,
                     orientation="side") for i in range(11)]
    old_way = replace(VISION_GATE, heading_min_m=8.0, heading_window_s=3.0)
    for back, two in ((4.0, False), (6.0, True), (8.0, True)):
        target = [sight(town01, 67.5 + 0.5 * i, 12, 105.0 - back + 0.5 * i, obs=4,
                        track=55, orientation="side") for i in range(11)]
        vision = gate_tracks(town01, [crawler, target], anchor=1, config=VISION_GATE)
        assert vision.accepted == ((1,) if two else (0, 1))
        for lenient in (GateConfig(), old_way):
            assert gate_tracks(town01, [crawler, target], anchor=1,
                               config=lenient).accepted == (0, 1)
    assert (VISION_GATE.heading_min_m, VISION_GATE.heading_window_s) == (3.0, 5.0)
