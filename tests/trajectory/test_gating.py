"""Spatio-temporal gating on the real Town01, with hand-built sightings.

Road 12 of Town01 is straight along +x (x 101 → 326 m at y ≈ 199) with driving
lanes -1 (along +s, +x) and 1 (against it); road 6 is the parallel street at
y ≈ 331 and road 4 the one at y ≈ 133: 130 m away, and hundreds of metres by road
(through the junctions at either end). Skipped when ``../shared/maps/carla`` is
missing.
"""

from __future__ import annotations

import math

import pytest

from dashtraj.trajectory.gating import (
    GateConfig,
    GatingError,
    gate_tracks,
    reachable,
)
from gating_helpers import drive, sight


def test_true_chain_kept_far_twin_dropped(town01):
    t1 = drive(town01, 0.0, 2.0, 12, 20.0, obs=1)      # s 20 → 40
    twin = drive(town01, 4.0, 5.0, 6, 100.0, obs=2)    # another street, 130 m away
    t2 = drive(town01, 10.0, 12.0, 12, 120.0, obs=3)   # s 120 → 140: 8 s after t1's end
    t3 = drive(town01, 18.0, 20.0, 12, 200.0, obs=4)
    r = gate_tracks(town01, [t1, twin, t2, t3])
    assert r.accepted == (0, 2, 3)
    assert r.rejected == (1,)
    assert r.weight == 3.0
    assert r.order == (0, 1, 2, 3)


def test_early_false_match_does_not_poison_the_chain(town01):
    # A greedy gate starting from the first candidate keeps the false match and then
    # rejects every true one (none is reachable from road 6 in time); the best chain
    # drops the false match instead.
    false = drive(town01, 0.0, 1.0, 6, 100.0, obs=2)
    t1 = drive(town01, 2.0, 4.0, 12, 20.0, obs=1)
    t2 = drive(town01, 12.0, 14.0, 12, 120.0, obs=3)
    t3 = drive(town01, 20.0, 22.0, 12, 200.0, obs=4)
    assert not reachable(town01, false[-1], t1[0])
    assert not reachable(town01, false[-1], t2[0])
    r = gate_tracks(town01, [false, t1, t2, t3])
    assert r.accepted == (1, 2, 3) and r.rejected == (0,)
    # Anchored on the false match (its track held the query), the chain through it wins.
    ra = gate_tracks(town01, [false, t1, t2, t3], anchor=0)
    assert ra.accepted[0] == 0 and 1 not in ra.accepted and 2 not in ra.accepted


def test_anchor_in_the_middle_keeps_both_sides(town01):
    t1 = drive(town01, 0.0, 2.0, 12, 20.0, obs=1)
    twin = drive(town01, 9.0, 10.0, 4, 120.0, obs=2)    # road 4 at the same time as t2
    t2 = drive(town01, 10.0, 12.0, 12, 120.0, obs=3)
    t3 = drive(town01, 18.0, 20.0, 12, 200.0, obs=4)
    r = gate_tracks(town01, [t1, twin, t2, t3], anchor=2)
    assert r.accepted == (0, 2, 3) and r.rejected == (1,)


def test_speed_bound_exact(town01):
    a = sight(town01, 0.0, 12, 20.0)
    cfg = GateConfig(max_speed_mps=25.0, slack_m=20.0, radius_m=0.5)
    cost = town01.lane_graph(0.0).route_cost(town01.waypoint(12, 0, -1, 20.0),
                                             town01.waypoint(12, 0, -1, 200.0))
    assert cost == pytest.approx(180.0, abs=1.0)  # straight road: progress difference
    dt_exact = (cost - cfg.slack_m) / cfg.max_speed_mps   # 6.4 s
    assert reachable(town01, a, sight(town01, dt_exact + 0.01, 12, 200.0), cfg)
    assert not reachable(town01, a, sight(town01, dt_exact - 0.01, 12, 200.0), cfg)
    # The default 54 km/h gate rejects 180 m in 8 s; the same pair at 11 s is fine.
    assert not reachable(town01, a, sight(town01, 8.0, 12, 200.0))
    assert reachable(town01, a, sight(town01, 11.0, 12, 200.0))
    # The route, not the straight line: road 4 runs parallel 66 m away, but the way
    # there goes through a junction at the end of the block (> 250 m).
    a100, b = sight(town01, 0.0, 12, 100.0), sight(town01, 3.0, 4, 100.0)
    straight = ((a100.x - b.x) ** 2 + (a100.y - b.y) ** 2) ** 0.5
    assert straight < cfg.max_speed_mps * 3.0 + cfg.slack_m
    assert not reachable(town01, a100, b, cfg)
    # Both positions read on the other side of the road (lane 1, driving -x) are a
    # consistent reading: 20 m "backwards" in 1 s is a car on the opposite lane. The
    # gate keeps it -- a lenient gate never rejects a pair some reading explains.
    assert reachable(town01, sight(town01, 0.0, 12, 100.0), sight(town01, 1.0, 12, 80.0), cfg)


def test_lane_ambiguity_handled_like_algorithm_1(town01):
    # The target drives lane -1 (+x), but its first position was pushed across the road
    # centre onto lane 1 (which drives -x). Taken literally, reaching s=120 on lane -1
    # from lane 1 at s=40 means driving around a block; Algorithm 1's correction (a
    # "back" view from an observer on lane -1: same direction) puts it on lane -1, 80 m
    # behind. The lane radius is kept tiny so that only the correction can help.
    g = town01.lane_graph(0.0)
    naive = g.route_cost(town01.waypoint(12, 0, 1, 40.0), town01.waypoint(12, 0, -1, 120.0))
    cfg = GateConfig(radius_m=0.5)
    budget = cfg.max_speed_mps * 6.0 + cfg.slack_m           # 110 m
    assert naive > budget
    a = sight(town01, 0.0, 12, 40.0, lane=1, orientation="back")
    b = sight(town01, 6.0, 12, 120.0)
    assert reachable(town01, a, b, cfg)
    # a side view carries no direction, yet the other-side lane is still a reading
    assert reachable(town01, sight(town01, 0.0, 12, 40.0, lane=1, orientation="side"), b, cfg)


def test_overlapping_tracks_of_two_observers(town01):
    # two observers see the target at once (s 20 → 60 and 40 → 80 on road 12):
    # consistent; a look-alike seen at the same time on road 4 is not
    t1 = drive(town01, 0.0, 4.0, 12, 20.0, obs=1)
    t2 = drive(town01, 2.0, 6.0, 12, 40.0, obs=2)
    twin = drive(town01, 3.0, 6.0, 4, 100.0, obs=3)
    r = gate_tracks(town01, [t2, twin, t1])
    assert r.accepted == (2, 0) and r.rejected == (1,)
    assert r.order == (2, 0, 1)


def test_weights_decide_between_exclusive_chains(town01):
    t1 = drive(town01, 0.0, 2.0, 12, 20.0, obs=1)
    t2 = drive(town01, 10.0, 12.0, 12, 120.0, obs=2)
    twin = drive(town01, 11.0, 12.0, 4, 120.0, obs=3)
    assert gate_tracks(town01, [t1, t2, twin]).accepted == (0, 1)
    heavy = gate_tracks(town01, [t1, t2, twin], weights=[1.0, 1.0, 5.0])
    # road 4 is > 300 m from t1's end by road: the twin stands alone, and outweighs both
    assert heavy.accepted == (2,) and heavy.weight == 5.0 and heavy.rejected == (0, 1)
    # at 144 km/h, with lane directions free, t1 (ends at s=40, t=2) could reach road 4's
    # lane 1 (driving -x) in 9 s: the set t1 + twin; the twin's own displacement (+x,
    # 10 m) says it drives lane -1, which is a whole block further: alone again
    free = GateConfig(max_speed_mps=40.0, heading_min_m=math.inf)
    fast = gate_tracks(town01, [t1, t2, twin], weights=[1.0, 1.0, 5.0], config=free)
    assert fast.accepted == (0, 2) and fast.weight == 6.0
    fast = gate_tracks(town01, [t1, t2, twin], weights=[1.0, 1.0, 5.0],
                       config=GateConfig(max_speed_mps=40.0))
    assert fast.accepted == (2,)


def test_empty_and_bad_input(town01):
    assert gate_tracks(town01, []).accepted == ()
    t = drive(town01, 0.0, 1.0, 12, 20.0)
    with pytest.raises(GatingError, match="track 1 has no sightings"):
        gate_tracks(town01, [t, []])
    with pytest.raises(GatingError, match="weight 0"):
        gate_tracks(town01, [t], weights=[float("nan")])
    with pytest.raises(GatingError, match="1 tracks but 2 weights"):
        gate_tracks(town01, [t], weights=[1.0, 2.0])
    with pytest.raises(GatingError, match="anchor 3"):
        gate_tracks(town01, [t], anchor=3)
    with pytest.raises(GatingError, match=r"apart pair \(0, 1\)"):
        gate_tracks(town01, [t], apart=[(0, 1)])
    with pytest.raises(GatingError, match=r"together pair \(0, -1\)"):
        gate_tracks(town01, [t], together=[(0, -1)])
    with pytest.raises(GatingError, match="max_speed_mps"):
        GateConfig(max_speed_mps=-1.0)
    with pytest.raises(GatingError, match="earlier"):
        reachable(town01, t[1], t[0])


def test_clique_checks_every_pair_the_chain_only_neighbours(town01):
    # The target on road 12 (observer 1's long track, t 0-12, s 20 -> 140; observer 2's
    # short one, t 1-2; observer 4's, t 20-21 at s 220). A look-alike 50 m ahead of it on
    # the same lane at t 10-11: reachable from the short track's end (130 m in 8 s) and
    # on to the last one, so a chain of consecutive pairs keeps it; but it is not where
    # the long track is at the same moment, so the consistent set drops it.
    long_ = drive(town01, 0.0, 12.0, 12, 20.0, obs=1)
    short = drive(town01, 1.0, 2.0, 12, 30.0, obs=2)
    twin = drive(town01, 10.0, 11.0, 12, 170.0, obs=3)
    last = drive(town01, 20.0, 21.0, 12, 220.0, obs=4)
    tracks = [long_, short, twin, last]
    chain = gate_tracks(town01, tracks, anchor=0, method="chain")
    assert chain.accepted == (0, 1, 2, 3)
    clique = gate_tracks(town01, tracks, anchor=0)
    assert clique.accepted == (0, 1, 3) and clique.rejected == (2,)
    with pytest.raises(GatingError, match="unknown gating method 'greedy'; valid: clique, chain"):
        gate_tracks(town01, tracks, method="greedy")


def test_jitter_behind_is_not_a_loop(town01):
    # Driving +x on road 12 (lane -1): an estimate 5 m behind the previous one half a
    # second later is localization jitter; 30 m behind is not (> slack_m = 20 m), and
    # with the heading known the opposite lane is no reading either.
    east = (1.0, 0.0)
    a = sight(town01, 0.0, 12, 100.0)
    assert reachable(town01, a, sight(town01, 0.5, 12, 95.0), heading_a=east, heading_b=east)
    assert not reachable(town01, a, sight(town01, 0.5, 12, 70.0), heading_a=east,
                         heading_b=east)
    # without the heading, lane 1 (driving -x) explains 30 m "backwards" in 0.5 s at
    # 15 m/s + 20 m slack
    assert reachable(town01, a, sight(town01, 0.5, 12, 75.0))


def test_one_cameras_simultaneous_tracks_are_two_vehicles(town01):
    # observer 1 follows the target (track 1) and, for a second, also sees a look-alike
    # beside it (track 2): close enough for any position reading, but one camera's two
    # tracks at one moment are two vehicles; the same look-alike seen by another
    # observer (3) could be the target's own track
    target = drive(town01, 0.0, 6.0, 12, 20.0, obs=1, track=1)
    beside = [sight(town01, t, 12, 20.0 + 10.0 * t + 3.0, lane=1, obs=1, track=2)
              for t in (2.0, 2.5)]
    r = gate_tracks(town01, [target, beside], anchor=0)
    assert r.accepted == (0,) and r.rejected == (1,)
    other_cam = [sight(town01, t, 12, 20.0 + 10.0 * t + 3.0, lane=1, obs=3, track=2)
                 for t in (2.0, 2.5)]
    assert gate_tracks(town01, [target, other_cam], anchor=0).accepted == (0, 1)


def test_one_cameras_duplicate_track_of_one_vehicle_is_kept(town01):
    # the same camera's second track on the target itself (a second box of another
    # orientation class, or a track restarted while the old one coasted): seen at the
    # same moments 0.5 m from the first track, so one vehicle, and both are the target's
    target = drive(town01, 0.0, 6.0, 12, 20.0, obs=1, track=1)
    dup = [sight(town01, t, 12, 20.0 + 10.0 * t + 0.5, obs=1, track=2) for t in (2.0, 2.5, 3.0)]
    assert gate_tracks(town01, [target, dup], anchor=0).accepted == (0, 1)
    # 4 m ahead at the same moments: another vehicle (a lane or a car length away)
    ahead = [sight(town01, t, 12, 20.0 + 10.0 * t + 4.0, obs=1, track=2) for t in (2.0, 2.5)]
    assert gate_tracks(town01, [target, ahead], anchor=0).accepted == (0,)
    # unless the camera's pixels showed the two tracks as one vehicle (overlapping boxes:
    # a second box on part of it is localized metres away); reachability still applies
    assert gate_tracks(town01, [target, ahead], anchor=0, together=[(0, 1)]).accepted == (0, 1)
    far = [sight(town01, t, 6, 100.0, obs=1, track=2) for t in (2.0, 2.5)]
    assert gate_tracks(town01, [target, far], anchor=0, together=[(0, 1)]).accepted == (0,)
    # same_camera_m = 0: the earlier rule, any overlap in time is two vehicles
    old = GateConfig(same_camera_m=0.0)
    assert gate_tracks(town01, [target, dup], anchor=0, config=old).accepted == (0,)
    # sampled on another clock (the gate sees one sighting per 0.5 s of each track): the
    # other track's position is interpolated at each sighting's moment
    alt = [sight(town01, t, 12, 20.0 + 10.0 * t, obs=1, track=2) for t in (2.25, 2.75)]
    assert gate_tracks(town01, [target, alt], anchor=0).accepted == (0, 1)
    alt_ahead = [sight(town01, t, 12, 24.0 + 10.0 * t, obs=1, track=2) for t in (2.25, 2.75)]
    assert gate_tracks(town01, [target, alt_ahead], anchor=0).accepted == (0,)
    with pytest.raises(GatingError, match="same_camera_m"):
        GateConfig(same_camera_m=-1.0)


def test_pairs_known_apart_are_never_both_kept(town01):
    # observer 1 follows the target (track 1); an oncoming car passes it across the road
    # centre (track 2, lane 1) while the target is beyond the ReID range, so the gate
    # holds no sighting of track 1 at those moments: by positions alone both tracks
    # could be the target (track 2 is reachable from track 1's last sighting and back)
    target = (drive(town01, 0.0, 2.0, 12, 20.0, obs=1, track=1)
              + drive(town01, 6.0, 8.0, 12, 80.0, obs=1, track=1))
    oncoming = [sight(town01, t, 12, 20.0 + 10.0 * t + 3.0, lane=1, obs=1, track=2,
                      orientation="front") for t in (4.0, 4.5)]
    assert gate_tracks(town01, [target, oncoming], anchor=0).accepted == (0, 1)
    # the pixels said two vehicles (separate boxes in the same frames): only the anchor stays
    r = gate_tracks(town01, [target, oncoming], anchor=0, apart=[(1, 0)])
    assert r.accepted == (0,) and r.rejected == (1,)
    # without an anchor the heavier track stays, whichever index comes first in the pair
    r = gate_tracks(town01, [oncoming, target], weights=[2.0, 10.0], apart=[(0, 1)])
    assert r.accepted == (1,)


def test_one_vehicle_seen_by_two_cameras_stands_or_falls_whole(town01):
    """A twin 30 m behind the target on road 12, seen at once by observer 3 (1 s) and
    observer 4 (9 s, until the target's second track has begun, 30 m ahead of it).
    Observer 3's short track alone fits the target's route; observer 4's cannot (two
    places at one moment). The two tracks place their car on the same spot at the same
    moments (`co_observed`): one vehicle, so the gate drops both; without the rule
    observer 3's track of the twin is accepted as the target."""
    from dataclasses import replace

    from dashtraj.trajectory.gating import co_observed

    target = drive(town01, 0.0, 2.0, 12, 20.0, speed=5.0, obs=1)          # s 20 → 30
    later = drive(town01, 14.0, 30.0, 12, 90.0, speed=5.0, obs=2)         # s 90 → 170
    twin3 = drive(town01, 6.0, 7.0, 12, 20.0, speed=5.0, obs=3, track=7)  # s 20 → 25
    twin4 = drive(town01, 6.0, 15.0, 12, 20.0, speed=5.0, obs=4, track=8)  # s 20 → 65
    assert co_observed(twin3, twin4, 2.5) and not co_observed(twin3, target, 2.5)
    assert not co_observed(twin3, twin3, 2.5)  # one observer: not this rule
    shifted = [replace(s, x=s.x + 4.0) for s in twin4]
    assert not co_observed(twin3, shifted, 2.5)  # a car length (or a lane) away: two cars
    tracks = [target, later, twin3, twin4]
    w = [len(t) for t in tracks]
    whole = gate_tracks(town01, tracks, weights=w, anchor=0)
    assert whole.accepted == (0, 1) and whole.rejected == (2, 3)
    apart = gate_tracks(town01, tracks, weights=w, anchor=0,
                        config=GateConfig(co_observed_m=0.0))
    assert apart.accepted == (0, 2, 1) and apart.rejected == (3,)
    with pytest.raises(GatingError, match="co_observed_m"):
        GateConfig(co_observed_m=-1.0)


def test_tracks_seen_only_before_the_first_sighting_are_rejected(town01):
    early = drive(town01, 0.0, 2.0, 12, 0.0, obs=2)     # reachable, but before start_t
    first = drive(town01, 5.0, 7.0, 12, 60.0, obs=1)
    later = drive(town01, 10.0, 12.0, 12, 110.0, obs=3)
    assert gate_tracks(town01, [early, first, later], anchor=1).accepted == (0, 1, 2)
    r = gate_tracks(town01, [early, first, later], anchor=1, start_t=5.0)
    assert r.accepted == (1, 2) and r.rejected == (0,) and r.order == (0, 1, 2)
    assert r.weight == 2.0
