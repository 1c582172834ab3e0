"""`dashtraj reidentify`: the experiments' re-identification with the query a track the user
points at; on the track the experiments' query falls in, the same decision and sightings."""

from __future__ import annotations

import itertools
import json
import shutil

import pytest

from dashtraj.cli import main
from dashtraj.store import SightingsDB
from dashtraj.trajectory.io import write_sightings


@pytest.fixture
def copied_run(small_run, small_db, tmp_path):
    """(a copy of `small_db`, the target's id, ``run(**kw)``: `target_from_db` on that copy
    as the experiments call it, with the shipped ReID model and its threshold)."""
    from dashtraj.reid.embed import ReidEmbedder, shipped_model_path
    from dashtraj.reidentify.vision import load_threshold, target_from_db
    from dashtraj.roads import RoadMap

    db = tmp_path / "run.db"
    shutil.copy(small_db[0], db)
    target = int(small_run.meta["target_vehicle_id"])
    th = load_threshold(shipped_model_path())
    road_map = RoadMap.from_file(small_run.map_path)
    emb = ReidEmbedder(shipped_model_path(), threads=2)

    def run(**kw):
        return target_from_db(db, road_map, target, embedder=emb,
                              threshold=th.calibration.threshold, recipe=th.calibration.recipe,
                              sample_s=0.5, **kw)

    return db, target, run


def test_reidentify_a_pointed_track_as_the_experiments_do(copied_run, small_run, tmp_path,
                                                          capsys):
    db, target, run = copied_run
    ref = run(route_m=20.0)  # the experiments' default route range, and reidentify's
    q = ref.summary["query"]
    with SightingsDB.open(db) as d:
        (tid,) = {x.track_id for x in d.detections(q["observer_id"]) if x.frame == q["frame"]
                  and x.truth_vehicle_id == target}
    assert ref.sightings and ref.summary["reid_precision"] == 1.0
    expected = tmp_path / "expected.csv"
    write_sightings(expected, ref.sightings)
    args = ["reidentify", str(db), "--track", f"{q['observer_id']}:{tid}", "--map",
            str(small_run.map_path), "--json"]
    assert main([*args, "-o", str(tmp_path / "scored.csv"), "--vehicle", str(target)]) == 0
    scored = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert main([*args, "-o", str(tmp_path / "plain.csv")]) == 0
    plain = json.loads(capsys.readouterr().out.splitlines()[-1])
    for name in ("scored.csv", "plain.csv"):
        assert (tmp_path / name).read_bytes() == expected.read_bytes()
    keys = sorted([list(k) for k in ref.true_match])
    assert scored["accepted_tracks"] == plain["accepted_tracks"] == keys
    assert scored["reid_precision"] == 1.0 and "reid_precision" not in plain
    assert plain["query"] == q and plain["sightings"] == len(ref.sightings)


def test_reidentify_refuses_a_missing_track_in_one_line(small_run, small_db, tmp_path, capsys):
    out = tmp_path / "s.csv"
    assert main(["reidentify", str(small_db[0]), "--track", "1:999", "--map",
                 str(small_run.map_path), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--track 1:999: no such track" in err and err.count("\n") == 1
    assert not out.exists()


def test_a_wider_gallery_adds_far_sightings_and_keeps_the_query(copied_run, small_run,
                                                                tmp_path, capsys):
    """``gallery_m``: the sightings (and the gallery) reach farther, the query stays the
    target's first crop within ``max_distance_m``; a gallery nearer than the query's range
    is refused (and by ``reidentify --gallery-range``, in one line)."""
    from dashtraj.reidentify.vision import VisionReidError

    db, target, run = copied_run
    base, same, wide = run(), run(gallery_m=15.0), run(gallery_m=40.0)
    assert same.sightings == base.sightings and same.summary == base.summary
    assert wide.summary["query"] == base.summary["query"]
    assert max(s.distance for s in base.sightings) <= 15.0
    far = [s for s in wide.sightings if s.distance > 15.0]
    assert far and max(s.distance for s in wide.sightings) <= 40.0
    assert len(wide.sightings) > len(base.sightings)
    assert wide.summary["reid_tracks"] >= base.summary["reid_tracks"]
    with pytest.raises(VisionReidError, match=r"gallery's range \(10.0 m\) must be at least"):
        run(gallery_m=10.0)
    out = tmp_path / "s.csv"
    q = base.summary["query"]
    with SightingsDB.open(db) as d:
        (tid,) = {x.track_id for x in d.detections(q["observer_id"]) if x.frame == q["frame"]
                  and x.truth_vehicle_id == target}
    capsys.readouterr()
    assert main(["reidentify", str(db), "--track", f"{q['observer_id']}:{tid}", "--map",
                 str(small_run.map_path), "--gallery-range", "10", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "gallery's range (10.0 m) must be at least the query's (15 m)" in err
    assert err.count("\n") == 1 and not out.exists()


def test_a_route_range_adds_the_accepted_tracks_farther_sightings(copied_run):
    """``route_m``: the same decisions, and the accepted tracks' detections beyond 15 m
    (one every ``sample_s`` per track) join the sightings; a route range under the
    gallery's is refused."""
    from dashtraj.reidentify.vision import VisionReidError

    run = copied_run[2]
    base, wide = run(), run(route_m=40.0)
    assert set(wide.true_match) == set(base.true_match)  # the same accepted tracks
    for k in ("reid_precision", "reid_recall", "reid_candidates", "query"):
        assert wide.summary[k] == base.summary[k]
    near = [s for s in wide.sightings if s.distance <= 15.0]
    far = [s for s in wide.sightings if s.distance > 15.0]
    assert near == base.sightings and far
    assert wide.summary["route_sightings_beyond"] == len(far)
    tracks = {(s.observer_id, s.track_id) for s in base.sightings}
    assert {(s.observer_id, s.track_id) for s in far} <= tracks
    assert max(s.distance for s in far) <= 40.0
    for key in tracks:  # at most one farther sighting per track and half second
        ts = sorted(s.t for s in far if (s.observer_id, s.track_id) == key)
        assert all(b - a > 0.25 for a, b in itertools.pairwise(ts))
    with pytest.raises(VisionReidError, match=r"route's range \(20.0 m\) must be at least "
                                              r"the gallery's \(25 m\)"):
        run(gallery_m=25.0, route_m=20.0)
