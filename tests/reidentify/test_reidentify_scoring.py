"""Precision and recall of accepted target tracks against the truth."""

from __future__ import annotations

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
