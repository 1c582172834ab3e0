"""Decision + gate on Town01: an exact look-alike passes the appearance threshold, the
gate removes it (road 12 vs the parallel road 4, see tests/trajectory/test_gating.py)."""

from __future__ import annotations

import numpy as np

from dashtraj.reidentify.scoring import reid_score
from dashtraj.reidentify.select import select_target_tracks
from gating_helpers import drive


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
