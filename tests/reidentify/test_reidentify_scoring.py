"""Precision and recall of accepted target tracks against the truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dashtraj.reidentify.scoring import ReidScore, ReidScoreError, pool, reid_score, truth_of_tracks
from dashtraj.store import DetectionRow, PoseRow, SightingsDB, TrackRow


def test_counts_and_rates():
    truth = {(1, 4): 0, (1, 5): 9, (2, 7): 5, (3, 1): 0, (3, 2): 0, (4, 1): None}
    s = reid_score([(1, 4), (2, 7), (4, 1)], truth, target_vehicle_id=0)
    assert (s.true_matches, s.false_matches, s.misses) == (1, 2, 2)
    assert s.precision == pytest.approx(1 / 3) and s.recall == pytest.approx(1 / 3)
    perfect = reid_score([(1, 4), (3, 1), (3, 2)], truth, 0)
    assert (perfect.precision, perfect.recall) == (1.0, 1.0)
    empty = reid_score([], truth, 0)
    assert empty.precision is None and empty.recall == 0.0
    assert reid_score([], {(1, 1): 3}, 0).recall is None
    assert empty.to_dict()["reid_precision"] is None
    with pytest.raises(ReidScoreError, match=r"accepted track \(9, 9\)"):
        reid_score([(9, 9)], truth, 0)


def test_sightings_count_what_each_one_shows():
    from dashtraj.reidentify.scoring import sighting_score

    shown = [((1, 4), 0)] * 6 + [((1, 4), None)] * 2 + [((2, 7), 5)] * 3 \
        + [((3, 1), 0)] * 4 + [((3, 2), 0), ((3, 2), 9)]
    s = sighting_score(shown, [(1, 4), (2, 7)], 0)
    assert (s.true_matches, s.false_matches, s.misses) == (6, 5, 5)
    assert s.sightings_dict() == {"reid_sighting_precision": 6 / 11,
                                  "reid_sighting_recall": 6 / 11, "reid_sightings_true": 6,
                                  "reid_sightings_false": 5, "reid_sightings_missed": 5}
    none = sighting_score(shown, [], 0)
    assert none.precision is None and none.recall == 0.0


def test_pool_sums_counts_before_dividing():
    a, b = ReidScore(9, 0, 1), ReidScore(0, 1, 0)
    p = pool([a, b])
    assert (p.true_matches, p.false_matches, p.misses) == (9, 1, 1)
    assert p.precision == pytest.approx(0.9) and p.recall == pytest.approx(0.9)


def test_truth_from_a_sightings_db(tmp_path):
    path = tmp_path / "run.db"
    with SightingsDB.create(path) as db:
        db.write_run("runs/x", "town01", None, {}, {}, [(1, None)])
        poses = [PoseRow(1, f, f * 0.1, 0, 0, 0, 0, 0, 0, 1.6, 0, 0) for f in range(2)]
        dets = [DetectionRow(1, f, i, f * 0.1, 7 + i, 0, 0, 10, 10, 0.9, 1, "car", "back",
                             8.0 + 10 * i, 0.0, 1, 2, 0, None, None, None, None, None, 3 + i)
                for f in range(2) for i in range(2)]
        tracks = [TrackRow(1, 7, "car", 0.0, 0.1, 2, 3), TrackRow(1, 8, "car", 0.0, 0.1, 2, 4)]
        db.add_frames(poses, dets, (), tracks)
        db.finish_observer(1)
        db.finish_run()
    with SightingsDB.open(path) as db:
        assert truth_of_tracks(db) == {(1, 7): 3, (1, 8): 4}
        assert truth_of_tracks(db, max_distance_m=15.0) == {(1, 7): 3}  # track 8 at 18 m


def test_query_is_the_first_cropped_detection_in_range(tmp_path):
    from dashtraj.reidentify.select import query_detection, tracks_of
    from dashtraj.store import CropRow

    path = tmp_path / "q.db"
    with SightingsDB.create(path) as db:
        db.write_run("runs/x", "town01", None, {}, {}, [(1, None), (2, None)])
        for obs, t0 in ((1, 0.5), (2, 0.0)):
            poses = [PoseRow(obs, f, t0 + f * 0.1, 0, 0, 0, 0, 0, 0, 1.6, 0, 0) for f in range(3)]
            # the target (truth 0) at 20 m in frame 0 (out of range), 12 m after
            dets = [DetectionRow(obs, f, 0, t0 + f * 0.1, 5, 0, 0, 10, 10, 0.9, 1, "car", "back",
                                 20.0 if f == 0 else 12.0, 0.0, 1, 2, 0, None, None, None, None,
                                 None, 0) for f in range(3)]
            # observer 2's frame 1 has no crop
            crops = [CropRow(obs, f, 0, b"\xff", 1, 1) for f in range(3) if (obs, f) != (2, 1)]
            db.add_frames(poses, dets, crops, [TrackRow(obs, 5, "car", t0, t0 + 0.2, 3, 0)])
            db.finish_observer(obs)
        db.finish_run()
    with SightingsDB.open(path) as db:
        q = query_detection(db, 0)
        assert (q.observer_id, q.frame, q.t) == (2, 2, 0.2)  # 2's frame 0 too far, 1 no crop
        assert query_detection(db, 0, max_distance_m=25.0).frame == 0
        assert query_detection(db, 7) is None
        groups = tracks_of(db.sightings(max_distance_m=15.0))
        assert sorted(groups) == [(1, 5), (2, 5)]
        assert [s.t for s in groups[(1, 5)]] == [0.6, 0.7]


def test_the_route_gets_each_tracks_last_detection_in_range(tmp_path, town01):
    """Sightings are sampled every 0.5 s of a track; the target's sightings also end at
    each track's last detection within range (the route is rebuilt up to where the track
    really left it), while the decisions and the scoring see the samples only."""
    from dashtraj.reidentify.vision import StageSwitches, target_from_db

    path = tmp_path / "ends.db"
    with SightingsDB.create(path) as db:
        db.write_run("runs/x", "town01", None, {"width_px": 640, "height_px": 360}, {},
                     [(1, None)])
        poses = [PoseRow(1, f, f * 0.1, 0, 0, 0, 0, 0, 0, 1.6, 0, 0) for f in range(16)]
        # track 5: the target, in range in frames 0-12 (t 0-1.2 s), 20 m away after;
        # track 6: the target too, frames 0-10 (its last detection is a sample)
        dets = [DetectionRow(1, f, 0, f * 0.1, 5, 0, 0, 10, 10, 0.9, 1, "car", "back",
                             12.0 if f <= 12 else 20.0, 0.0, 100.0 + f, 2.0, 0, None, None, None,
                             None, None, 0) for f in range(16)]
        dets += [DetectionRow(1, f, 1, f * 0.1, 6, 20, 0, 30, 10, 0.9, 1, "car", "back", 10.0,
                              0.0, 50.0 + f, 2.0, 0, None, None, None, None, None, 0)
                 for f in range(11)]
        db.add_frames(poses, dets, (), [TrackRow(1, 5, "car", 0.0, 1.5, 16, 0),
                                        TrackRow(1, 6, "car", 0.0, 1.0, 11, 0)])
        db.finish_observer(1)
        db.finish_run()
    tt = target_from_db(path, town01, 0, switches=StageSwitches(reid="identity"),
                        max_distance_m=15.0, sample_s=0.5)
    by_track = {k: [round(s.t, 3) for s in tt.sightings if s.track_id == k] for k in (5, 6)}
    assert by_track == {5: [0.0, 0.5, 1.0, 1.2], 6: [0.0, 0.5, 1.0]}
    end = [s for s in tt.sightings if s.track_id == 5][-1]
    assert (end.x, end.y) == (112.0, 2.0)  # frame 12's position
    assert (tt.summary["reid_true_matches"], tt.summary["reid_misses"]) == (2, 0)


def _road12_db(path, m, rows_of, tracks):
    """A sightings DB of observer 1 driving Town01's road 12 (lane -1) at 10 m/s from
    s = 10 m, a frame every 0.2 s for 20 frames. ``rows_of(f, t)`` gives a frame's
    detections as (track, box, score, location, truth id, depicted id, axis); each has a
    crop whose embedding for the shipped ReID model is the unit vector along ``axis`` (of the
    model's embedding size).
    ``tracks``: the `TrackRow`s. Returns the model's path."""
    from dashtraj.reid.database import file_sha256
    from dashtraj.reid.embed import ReidEmbedder, shipped_model_path
    from dashtraj.store import CropRow

    model = shipped_model_path()
    dim = ReidEmbedder(model, threads=1).dim
    with SightingsDB.create(path) as db:
        db.write_run("runs/x", "town01", None, {"width_px": 640, "height_px": 360}, {},
                     [(1, None)])
        poses, dets, crops, keys, vecs = [], [], [], [], []
        for f in range(20):
            t = f * 0.2
            o = m.waypoint(12, 0, -1, 10.0 + 10.0 * t).transform
            poses.append(PoseRow(1, f, t, o.location.x, o.location.y, 0.0, o.rotation.yaw,
                                 o.location.x, o.location.y, 1.6, o.rotation.yaw, 0.0))
            for idx, (track, box, score, p, vid, dep, axis) in enumerate(rows_of(f, t)):
                dets.append(DetectionRow(1, f, idx, t, track, *box, score, 1, "car", "back",
                                         10.0, 0.0, p.x, p.y, 0.0, None, None, None, None, None,
                                         vid, dep))
                crops.append(CropRow(1, f, idx, b"\xff", 1, 1))
                keys.append((1, f, idx))
                vecs.append(np.eye(dim, dtype=np.float32)[axis])
        db.add_frames(poses, dets, crops, tracks)
        db.add_embeddings(model.name, file_sha256(model), keys, np.array(vecs))
        db.finish_observer(1)
        db.finish_run()
    return model


def _switch_db(path, m):
    """Observer 1 follows the target (vehicle 0) along Town01's road 12. Its tracker
    swaps identities at t = 2.4 s: track 5 holds the target's boxes until then and an
    oncoming car's (vehicle 7, on the other lane) after; track 6 picks the target up.
    The crops' embeddings are stored for the shipped ReID model: the target's along one
    axis, the other car's along another (cosine distance 1)."""

    def rows_of(f, t):
        target = m.waypoint(12, 0, -1, 20.0 + 10.0 * t).transform.location
        other = m.waypoint(12, 0, 1, 80.0 - 10.0 * t).transform.location
        if f < 12:
            return [(5, (300, 150, 360, 200), 0.9, target, 0, 0, 0)]
        return [(5, (500, 150, 540, 190), 0.9, other, 7, 7, 1),
                (6, (300, 150, 360, 200), 0.9, target, 0, 0, 0)]

    return _road12_db(path, m, rows_of, [TrackRow(1, 5, "car", 0.0, 3.8, 20, 0),
                                         TrackRow(1, 6, "car", 2.4, 3.8, 8, 0)])


def test_a_track_that_switches_vehicle_is_cut_where_its_look_changes(tmp_path, town01):
    """Uncut, track 5 is the target by its median (12 of its 20 crops), carries the
    oncoming car's positions into the route, and its boxes beside track 6's say two
    vehicles, so the gate drops track 6, the target's. Cut at the switch, the car's part
    fails the threshold and both of the target's tracks are kept."""
    from dashtraj.reid.embed import ReidEmbedder
    from dashtraj.reidentify.decision import EXPANDED_RECIPE
    from dashtraj.reidentify.vision import target_from_db

    path = tmp_path / "switch.db"
    embedder = ReidEmbedder(_switch_db(path, town01), threads=1)
    kw = dict(embedder=embedder, threshold=0.4, recipe=EXPANDED_RECIPE, sample_s=0.5)
    whole = target_from_db(path, town01, 0, split=False, **kw)
    assert (whole.summary["reid_true_matches"], whole.summary["reid_misses"]) == (1, 1)
    assert {s.track_id for s in whole.sightings} == {5}
    per_sighting = ("reid_sightings_true", "reid_sightings_false", "reid_sightings_missed")
    assert tuple(whole.summary[k] for k in per_sighting) == (5, 3, 3)
    assert whole.summary["reid_sighting_precision"] == pytest.approx(5 / 8)
    far = [s for s in whole.sightings if s.t > 2.3]  # the oncoming car's positions
    assert far and all(abs(s.y - whole.sightings[0].y) > 2.0 for s in far)

    cut = target_from_db(path, town01, 0, split=True, **kw)
    s = cut.summary
    assert (s["reid_true_matches"], s["reid_false_matches"], s["reid_misses"]) == (2, 0, 0)
    assert (s["reid_split_tracks"], s["reid_split_parts"]) == (1, 1)
    assert tuple(s[k] for k in per_sighting) == (8, 0, 0)
    assert (s["reid_sighting_precision"], s["reid_sighting_recall"]) == (1.0, 1.0)
    assert s["reid_candidates"] == 2  # (1, 5) and (1, 6); the car's part (1, 5, 1) fails
    assert [(x.track_id, round(x.t, 1)) for x in cut.sightings] == \
        [(5, 0.0), (5, 0.6), (5, 1.0), (5, 1.6), (5, 2.0), (5, 2.2),
         (6, 2.4), (6, 3.0), (6, 3.4), (6, 3.8)]
    y0 = cut.sightings[0].y
    assert all(abs(x.y - y0) < 0.5 for x in cut.sightings)  # the target's lane throughout


def _weak_box_db(path, m):
    """Observer 1 follows the target (vehicle 0) along Town01's road 12 on track 5. From
    t = 2.4 s the detector scores the target's box low for a while and boxes a part of it
    above (score 0.3, localized 8 m too far): the tracker keeps track 5 on the weak part
    box and starts track 6 on the target's confident box. Every crop shows the target (the
    shipped model's embeddings stored along one axis)."""

    def rows_of(f, t):
        target = m.waypoint(12, 0, -1, 20.0 + 10.0 * t).transform.location
        part = m.waypoint(12, 0, -1, 28.0 + 10.0 * t).transform.location
        if f < 12:
            return [(5, (300, 150, 360, 200), 0.9, target, 0, 0, 0)]
        return [(5, (310, 120, 350, 145), 0.3, part, None, 0, 0),
                (6, (300, 150, 360, 200), 0.9, target, 0, 0, 0)]

    return _road12_db(path, m, rows_of, [TrackRow(1, 5, "car", 0.0, 3.8, 20, 0),
                                         TrackRow(1, 6, "car", 2.4, 3.8, 8, 0)])


def test_weak_boxes_are_no_sightings(tmp_path, town01):
    """With every detection used, track 5's weak part boxes beside track 6's box say two
    vehicles (separate boxes in the same frames, positions 8 m apart), so the gate keeps
    one of the target's two tracks and the route gets the part box's wrong positions.
    Without the weak boxes (`SIGHTING_MIN_SCORE`), both tracks are the target's and every
    sighting is on it."""
    from dashtraj.reid.embed import ReidEmbedder
    from dashtraj.reidentify.decision import EXPANDED_RECIPE
    from dashtraj.reidentify.vision import SIGHTING_MIN_SCORE, target_from_db

    assert 0.3 < SIGHTING_MIN_SCORE <= 0.9
    path = tmp_path / "weak.db"
    embedder = ReidEmbedder(_weak_box_db(path, town01), threads=1)
    kw = dict(embedder=embedder, threshold=0.4, recipe=EXPANDED_RECIPE, sample_s=0.5)
    every = target_from_db(path, town01, 0, min_score=0.0, **kw).summary
    assert (every["reid_true_matches"], every["reid_false_matches"],
            every["reid_misses"]) == (1, 0, 1)
    assert every["reid_misses_by_cause"]["gate"] == 1

    tt = target_from_db(path, town01, 0, **kw)
    s = tt.summary
    assert (s["reid_true_matches"], s["reid_false_matches"], s["reid_misses"]) == (2, 0, 0)
    assert s["reid_min_score"] == SIGHTING_MIN_SCORE
    assert [(x.track_id, round(x.t, 1)) for x in tt.sightings] == \
        [(5, 0.0), (5, 0.6), (5, 1.0), (5, 1.6), (5, 2.0), (5, 2.2),
         (6, 2.4), (6, 3.0), (6, 3.4), (6, 3.8)]
    for x in tt.sightings:  # every sighting is the target's box, none the part box's
        p = town01.waypoint(12, 0, -1, 20.0 + 10.0 * x.t).transform.location
        assert math.hypot(x.x - p.x, x.y - p.y) < 1e-6


def test_the_query_is_a_tracked_crop(tmp_path, town01):
    """The target's first six boxes belong to no track (the tracker had not confirmed it
    yet): the query is its first crop of a track, and that track is the gate's anchor.
    A look-alike seen only before the query (track 7, the same look, 5 m ahead of the
    target until 0.4 s: the target could have driven on from there) is not the target."""
    from dashtraj.reid.embed import ReidEmbedder
    from dashtraj.reidentify.decision import EXPANDED_RECIPE
    from dashtraj.reidentify.vision import target_from_db

    def rows_of(f, t):
        target = town01.waypoint(12, 0, -1, 20.0 + 10.0 * t).transform.location
        twin = town01.waypoint(12, 0, -1, 25.0 + 10.0 * t).transform.location
        rows = [(None if f < 6 else 5, (300, 150, 360, 200), 0.9, target, 0, 0, 0)]
        if f < 3:
            rows.append((7, (400, 150, 460, 200), 0.9, twin, 9, 9, 0))
        return rows

    path = tmp_path / "untracked.db"
    model = _road12_db(path, town01, rows_of, [TrackRow(1, 5, "car", 1.2, 3.8, 14, 0),
                                               TrackRow(1, 7, "car", 0.0, 0.4, 3, 9)])
    kw = dict(embedder=ReidEmbedder(model, threads=1), threshold=0.4, recipe=EXPANDED_RECIPE,
              sample_s=0.5)
    paper = target_from_db(path, town01, 0, gate=False, **kw).summary
    assert (paper["reid_true_matches"], paper["reid_false_matches"]) == (1, 1)  # same look
    tt = target_from_db(path, town01, 0, **kw)
    s = tt.summary
    assert (s["query"]["observer_id"], s["query"]["frame"]) == (1, 6)
    assert (s["reid_true_matches"], s["reid_false_matches"], s["reid_misses"]) == (1, 0, 0)
    assert s["reid_candidates"] == 2 and s["reid_gated_out"] == 1
    assert {x.track_id for x in tt.sightings} == {5}


def test_a_young_track_that_jumps_to_another_box_is_cut(tmp_path, town01):
    """Track 6 follows the target until 1.6 s. Track 5 starts at 2.0 s on another car
    (vehicle 7, beside the target on the other lane) cut by the frame's left edge, and the
    tracker's gate joins the target's box elsewhere in the image 0.4 s later to it (as
    town10 seed 4's track 145 of the ten from pixels). The cut crop is not read, so the
    decision accepts track 5 on the target's crop; the other car's box is its one sampled
    sighting, so the track is a false match and that car's position joins the route. Cut
    where the young track jumped (`start_jumps`), the car's part has no crop to decide on
    and the target's part is a true match."""
    from dashtraj.reid.embed import ReidEmbedder
    from dashtraj.reidentify.decision import EXPANDED_RECIPE
    from dashtraj.reidentify.vision import start_jumps, target_from_db

    def rows_of(f, t):
        target = town01.waypoint(12, 0, -1, 20.0 + 10.0 * t).transform.location
        other = town01.waypoint(12, 0, 1, 20.0 + 10.0 * t).transform.location
        if f <= 8:
            return [(6, (300, 150, 360, 200), 0.9, target, 0, 0, 0)]
        if f == 10:
            return [(5, (0, 150, 60, 200), 0.9, other, 7, 7, 1)]
        if f == 12:
            return [(5, (400, 150, 460, 200), 0.9, target, 0, 0, 0)]
        return []

    path = tmp_path / "jump.db"
    model = _road12_db(path, town01, rows_of, [TrackRow(1, 6, "car", 0.0, 1.6, 9, 0),
                                               TrackRow(1, 5, "car", 2.0, 2.4, 2, 7)])
    kw = dict(embedder=ReidEmbedder(model, threads=1), threshold=0.4, recipe=EXPANDED_RECIPE,
              sample_s=0.5)
    whole = target_from_db(path, town01, 0, young_jump=0, **kw)
    s = whole.summary
    assert (s["reid_true_matches"], s["reid_false_matches"], s["reid_misses"]) == (1, 1, 0)
    assert "reid_jump_cuts" not in s
    car = town01.waypoint(12, 0, 1, 40.0).transform.location
    assert any(math.hypot(x.x - car.x, x.y - car.y) < 1e-6 for x in whole.sightings)

    with SightingsDB.open(path) as db:
        assert start_jumps(db.detections(), 2) == {(1, 5): [pytest.approx(2.2)]}
        assert start_jumps(db.detections(), 0) == {}
    cut = target_from_db(path, town01, 0, young_jump=2, **kw)
    s = cut.summary
    assert (s["reid_true_matches"], s["reid_false_matches"], s["reid_misses"]) == (2, 0, 0)
    assert s["reid_jump_cuts"] == 1
    for x in cut.sightings:  # every sighting is the target's box, none the car's
        p = town01.waypoint(12, 0, -1, 20.0 + 10.0 * x.t).transform.location
        assert math.hypot(x.x - p.x, x.y - p.y) < 1e-6
    assert [(x.track_id, round(x.t, 1)) for x in cut.sightings][-1] == (5, 2.4)


def test_only_a_young_tracks_jumps_are_cuts():
    """A jump counts before the track's ``young``-th box only; touching boxes share no pixel;
    untracked boxes and other observers' tracks are apart."""
    from types import SimpleNamespace

    from dashtraj.reidentify.vision import start_jumps

    def det(o, track, t, x0, idx=0):
        return SimpleNamespace(observer_id=o, track_id=track, t=t, idx=idx, x0=x0, y0=100.0,
                               x1=x0 + 50.0, y1=150.0)

    rows = [det(1, 3, 0.0, 0), det(1, 3, 0.2, 40), det(1, 3, 0.4, 300),  # 3rd box jumps
            det(1, 4, 1.0, 0), det(1, 4, 1.2, 50),  # touching at x = 50: a jump
            det(2, 3, 0.0, 500), det(2, 3, 0.2, 505), det(1, None, 0.1, 200, idx=1)]
    assert start_jumps(rows, 2) == {(1, 4): [pytest.approx(1.1)]}
    assert start_jumps(rows, 3) == {(1, 3): [pytest.approx(0.3)], (1, 4): [pytest.approx(1.1)]}
    assert start_jumps(rows[::-1], 3) == start_jumps(rows, 3)  # any order in
