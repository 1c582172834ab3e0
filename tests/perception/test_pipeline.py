"""`dashtraj perceive` end to end: database contents, CLI discipline, export → reconstruct."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dashtraj.cli import main
from dashtraj.store import SightingsDB
from dashtraj.trajectory.io import read_sightings, read_trajectory


def _truth_xy(rec):
    st = rec.states
    step = rec.meta["step_s"]
    k = np.round(st.column("t").to_numpy() / step).astype(int)
    v = st.column("vehicle_id").to_numpy()
    x, y = st.column("x").to_numpy(), st.column("y").to_numpy()
    return {(int(a), int(b)): (x[i], y[i]) for i, (a, b) in enumerate(zip(k, v, strict=True))}


def test_database_holds_every_frame_detection_and_crop(small_run, small_db):
    path, summary = small_db
    with SightingsDB.open(path) as db:
        poses = db.poses()
        dets = db.detections()
        assert [o["observer_id"] for o in db.observers()] == [1, 3]
        assert all(o["complete"] and o["frames"] == 251 for o in db.observers())
        assert len(poses) == summary.frames == 2 * 251  # 25 s at 10 fps, both ends
        assert len(dets) == summary.detections > 100
        # oracle detections carry their vehicle; every crop is a JPEG of a detection <= 15 m
        assert all(d.truth_vehicle_id is not None for d in dets)
        by_key = {(d.observer_id, d.frame, d.idx): d for d in dets}
        crops = db.crops()
        assert len(crops) == summary.crops > 10
        assert all(c.jpeg[:2] == b"\xff\xd8" for c in crops)
        assert all(by_key[(c.observer_id, c.frame, c.idx)].distance_m <= 20.0 for c in crops)
        # each detection is map-matched on town01, estimated near its vehicle
        truth = _truth_xy(small_run)
        err = np.array([np.hypot(d.x - truth[(d.frame, d.truth_vehicle_id)][0],
                                 d.y - truth[(d.frame, d.truth_vehicle_id)][1])
                        for d in dets if d.distance_m < 20])
        assert np.sqrt(np.mean(err**2)) < 1.5  # 320 x 180: 1 px is 4x coarser than 1280 x 720
        assert all(d.road_id is not None and d.lane_id != 0 for d in dets)
        # tracks: one truth vehicle each, ids confirmed after min_hits; the table agrees
        # with the boxes
        tracks = db.tracks()
        assert len(tracks) == summary.tracks >= 3
        assert all(t.truth_vehicle_id is not None for t in tracks)
        times: dict = {}
        for d in dets:
            if d.track_id is not None:
                times.setdefault((d.observer_id, d.track_id), []).append(d.t)
        assert {(t.observer_id, t.track_id): (t.n_detections, t.first_t, t.last_t)
                for t in tracks} == {k: (len(v), min(v), max(v)) for k, v in times.items()}


def test_export_then_reconstruct_runs_on_the_database(small_run, small_db, tmp_path, capsys):
    path, _ = small_db
    csv = tmp_path / "s.csv"
    assert main(["sightings", "export", str(path), "-o", str(csv), "--vehicle", "target"]) == 0
    rows = read_sightings(csv)
    assert len(rows) >= 3 and {r.observer_id for r in rows} == {1, 3}
    route = small_run.target_route.points
    d = [np.min(np.hypot(route[:, 0] - r.x, route[:, 1] - r.y)) for r in rows]
    assert max(d) < 2.0  # every exported sighting lies on the target's true route
    out = tmp_path / "t.csv"
    assert main(["reconstruct", "--map", str(small_run.map_path), "--sightings", str(csv),
                 "-o", str(out)]) == 0
    rec = read_trajectory(out)
    assert len(rec) >= 2
    near = [np.min(np.hypot(route[:, 0] - x, route[:, 1] - y)) for x, y in rec.points]
    assert np.median(near) < 3.0


def test_perceive_cli_refuses_existing_output_and_replaces_whole(small_run, gl_available,
                                                                 tmp_path, capsys):
    out = tmp_path / "run.db"
    args = ["perceive", str(small_run.path), "-o", str(out), "--observers", "3", "--every",
            "0.5", "--tracker", "sort", "--localizer", "paper", "-q", "--mot",
            str(tmp_path / "mot")]
    assert main(args) == 0
    first = SightingsDB.open(out).count("poses")
    assert first == 51
    mot = (tmp_path / "mot" / "3.txt").read_text().splitlines()
    assert mot and all(len(line.split(",")) == 10 for line in mot)
    assert main(args) == 2
    assert "exists" in capsys.readouterr().err
    assert main([*args[:7], "1.0", *args[8:], "--overwrite"]) == 0
    with SightingsDB.open(out) as db:
        assert db.count("poses") == 26 and db.run_info()["config"]["every_s"] == 1.0
    assert not list(tmp_path.glob(".run.db*"))  # no temporary sibling or WAL left behind


@pytest.mark.parametrize("bad, msg", [
    (["--tracker", "kalman"], "unknown tracker 'kalman'; valid: sort, ego"),
    (["--localizer", "lidar"], "unknown localizer 'lidar'; valid: paper, ground, fused"),
    (["--detector", "yolo"], "unknown detector 'yolo'"),
    (["--observers", "0"], "not observers"),
    (["--live-relink", "--tracker", "sort"], "--live-relink re-links the ego tracker's"),
    (["--live-relink", "--reid-model", "nope.onnx"], "--reid-model 'nope.onnx': no such"),
])
def test_perceive_bad_settings_are_one_line_errors(small_run, gl_available, tmp_path, capsys,
                                                   bad, msg):
    assert main(["perceive", str(small_run.path), "-o", str(tmp_path / "r.db"), "-q",
                 *bad]) == 2
    err = capsys.readouterr().err
    assert msg in err and err.count("\n") == 1
    assert not (tmp_path / "r.db").exists()


def test_live_relink_writes_its_ids_and_its_model(small_run, small_db, tmp_path):
    """`perceive` with `PerceiveConfig.live_relink`: the ids written are `LiveRelink`'s
    (one vehicle each here, the tracks table agreeing with the boxes, no more ids than the
    tracker's), its ReID model's sha256 is in the run's meta, and a run perceived without
    it takes no observers perceived with it."""
    from dashtraj.digest import file_sha256
    from dashtraj.perception.pipeline import PerceiveConfig, perceive, perceive_identity
    from dashtraj.reid.embed import shipped_model_path
    from dashtraj.store.append import StoreError, db_identity, same_run

    path, _ = small_db
    out = tmp_path / "live.db"
    cfg = PerceiveConfig(observers=(1, 3), live_relink=True)
    perceive(small_run, out, cfg)
    with SightingsDB.open(out) as db, SightingsDB.open(path) as plain:
        dets, tracks = db.detections(), db.tracks()
        assert db.meta()["relink_model_sha256"] == file_sha256(shipped_model_path())
        assert db.run_info()["config"]["live_relink"] is True
        vehicles: dict = {}
        for d in dets:
            if d.track_id is not None:
                vehicles.setdefault((d.observer_id, d.track_id), set()).add(d.truth_vehicle_id)
        assert all(len(v) == 1 for v in vehicles.values())
        assert {(t.observer_id, t.track_id): t.n_detections for t in tracks} == {
            k: sum(1 for d in dets if (d.observer_id, d.track_id) == k) for k in vehicles}
        assert 3 <= len(tracks) <= len(plain.tracks())
        assert len(dets) == len(plain.detections())
        with pytest.raises(StoreError, match="live_relink=False"):
            same_run(db_identity(plain), perceive_identity(small_run, cfg), path)
        same_run(db_identity(db), perceive_identity(small_run, cfg), out)


def test_two_workers_write_the_same_content(small_run, small_db, tmp_path):
    from dashtraj.perception.pipeline import PerceiveConfig, perceive

    path, _ = small_db
    other = tmp_path / "w2.db"
    perceive(small_run, other, PerceiveConfig(observers=(1, 3)), workers=2)
    _same_content(path, other)


def test_perceive_into_postgres_two_writers_give_the_file_s_content(small_run, small_db,
                                                                    pg_url, tmp_path, capsys):
    """--workers 2 into a PostgreSQL schema: each worker writes its observer in its own
    connection; the run reads back as the SQLite file of one writer, and exports the same
    CSV byte for byte."""
    import psycopg

    from dashtraj.store.backend import parse_url

    path, summary = small_db
    assert main(["perceive", str(small_run.path), "-o", pg_url, "--observers", "1", "3",
                 "--workers", "2", "-q", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["frames"] == summary.frames and "schema=" in info["db"]
    _same_content(path, pg_url)
    target = parse_url(pg_url)
    with psycopg.connect(target.conninfo) as c:
        left = c.execute("SELECT schema_name FROM information_schema.schemata WHERE "
                         "schema_name LIKE %s", (target.schema + "%",)).fetchall()
    assert left == [(target.schema,)]  # the partial schema was renamed, nothing else left
    for src, out in ((str(path), "file.csv"), (pg_url, "pg.csv")):
        assert main(["sightings", "export", src, "-o", str(tmp_path / out), "--vehicle",
                     "all", "--max-distance", "60"]) == 0
    assert (tmp_path / "pg.csv").read_bytes() == (tmp_path / "file.csv").read_bytes()
    assert len((tmp_path / "pg.csv").read_text().splitlines()) > 50


def test_perceive_into_postgres_refuses_replaces_whole_and_keeps_a_partial_run(
        small_run, gl_available, pg_url, capsys, monkeypatch):
    import psycopg

    from dashtraj.store.backend import parse_url

    args = ["perceive", str(small_run.path), "-o", pg_url, "--observers", "3", "--every",
            "1.0", "--tracker", "sort", "--localizer", "paper", "-q"]
    assert main(args) == 0
    with SightingsDB.open(pg_url) as db:
        assert db.count("poses") == 26
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "exists; pass --overwrite" in err and err.count("\n") == 1
    # Ctrl-C at the end of the run: the old run stays, the new one is kept as a partial schema
    with monkeypatch.context() as m:
        m.setattr(SightingsDB, "finish_run", lambda self: (_ for _ in ()).throw(
            KeyboardInterrupt()))
        assert main([*args[:7], "0.5", *args[8:], "--overwrite"]) == 130
    assert "kept the partial output in schema" in capsys.readouterr().err
    target = parse_url(pg_url)
    partial = target.with_schema(target.schema + "__partial_1")
    with SightingsDB.open(pg_url) as old, SightingsDB.open(partial) as part:
        assert old.count("poses") == 26 and part.count("poses") == 51
        assert not part.run_info()["complete"]
    assert main([*args[:7], "0.5", *args[8:], "--overwrite"]) == 0
    with SightingsDB.open(pg_url) as db:
        assert db.count("poses") == 51 and db.run_info()["complete"]
    # a schema that is not a dashtraj run is never replaced
    foreign = target.with_schema(target.schema + "_notes")
    with psycopg.connect(target.conninfo, autocommit=True) as c:
        c.execute(f'CREATE SCHEMA "{target.schema}_notes"')
        c.execute(f'CREATE TABLE "{target.schema}_notes".notes (a TEXT)')
        assert main([*args[:3], foreign, *args[4:], "--overwrite"]) == 2
        assert "not a dashtraj sightings database; it is not replaced" in capsys.readouterr().err
        assert c.execute(f'SELECT COUNT(*) FROM "{target.schema}_notes".notes').fetchone() == (0,)


def _same_content(path_a, path_b) -> None:
    with SightingsDB.open(path_a) as a, SightingsDB.open(path_b) as b:
        assert a.poses() == b.poses()
        assert a.detections() == b.detections()
        assert a.tracks() == b.tracks()
        assert a.crops() == b.crops()
        assert a.observers() == b.observers()


def test_pipelining_and_the_shared_filter_do_not_change_the_database(small_run, small_db,
                                                                     tmp_path, monkeypatch):
    """`small_db` is pipelined (a render thread, 2 frames detected at once) and its ego
    tracker is the smoothed localizer's filter; all in turn on one thread, and with two
    separate filters, the database is the same."""
    from dashtraj.perception.localize import TrackedLocalizer
    from dashtraj.perception.pipeline import PerceiveConfig, perceive

    path, _ = small_db
    serial = tmp_path / "serial.db"
    perceive(small_run, serial, PerceiveConfig(observers=(1, 3), parallel_frames=0))
    _same_content(path, serial)
    monkeypatch.setattr(TrackedLocalizer, "share_tracker", lambda self, tracker: False)
    twins = tmp_path / "twins.db"
    perceive(small_run, twins, PerceiveConfig(observers=(1, 3), parallel_frames=3))
    _same_content(path, twins)


def test_share_tracker_only_takes_a_fresh_tracker_of_the_same_settings():
    from dashtraj.perception.localize import PAPER_MU_H, TrackedLocalizer
    from dashtraj.perception.track import EgoTracker, SortTracker

    assert TrackedLocalizer().share_tracker(EgoTracker())
    assert TrackedLocalizer().share_tracker(EgoTracker(confirm_score=0.0))  # reporting only
    assert not TrackedLocalizer(mu_h=PAPER_MU_H + 1).share_tracker(EgoTracker())
    assert not TrackedLocalizer().share_tracker(EgoTracker(max_age_s=1.0))
    assert not TrackedLocalizer().share_tracker(SortTracker())
    used = EgoTracker()
    used._t = 0.0
    assert not TrackedLocalizer().share_tracker(used)


def test_ego_settings_name_every_field_but_its_state():
    """`share_tracker` compares `EgoTracker.SETTINGS`: a new field must join them (or the
    state below), else two filters of different settings could be taken for one."""
    from dataclasses import fields

    from dashtraj.perception.track import EgoTracker

    names = {f.name for f in fields(EgoTracker)}
    state = {n for n in names if n.startswith("_")} | {
        "name", "positions", "innovation_d2", "track_of", "position_cov", "measured"}
    assert set(EgoTracker.SETTINGS) == names - state


def test_render_ahead_gives_the_frames_of_recording_frames(small_run, gl_available):
    from dashtraj.datasets.frames import RenderAhead, recording_frames

    want = list(recording_frames(small_run, 2.0, (160, 90), [1, 3], msaa=0))
    with RenderAhead(small_run, [1, 3], 2.0, (160, 90), msaa=0, depth=2) as ahead:
        got = list(ahead.frames(1)) + list(ahead.frames(3))
    assert len(got) == len(want) > 10
    for a, b in zip(got, want, strict=True):
        assert (a.observer_id, a.frame, a.vehicle_ids) == (b.observer_id, b.frame, b.vehicle_ids)
        np.testing.assert_array_equal(a.frame_data.rgb, b.frame_data.rgb)
        np.testing.assert_array_equal(a.frame_data.instance, b.frame_data.instance)
        assert ([lab.visible_box for lab in a.frame_data.labels]
                == [lab.visible_box for lab in b.frame_data.labels])


def test_render_ahead_order_errors_and_early_close(small_run, gl_available, tmp_path):
    import threading
    import time
    from types import SimpleNamespace

    from dashtraj.datasets.frames import RenderAhead

    with RenderAhead(small_run, [1, 3], 1.0, (160, 90), depth=1) as ahead:
        with pytest.raises(ValueError, match="observer 3 requested, the next one is 1"):
            next(ahead.frames(3))
        next(ahead.frames(1))  # one frame taken, the thread blocked on a full queue
        t0 = time.perf_counter()
    assert time.perf_counter() - t0 < 5.0
    assert not any(t.name == "dashtraj-render" for t in threading.enumerate())
    # an error in the thread (here: the map cannot be read) is raised by frames()
    bad = SimpleNamespace(config=small_run.config, map_path=tmp_path / "missing.xodr")
    with RenderAhead(bad, [1], 1.0, (160, 90)) as ahead, pytest.raises(Exception,
                                                                        match=r"missing\.xodr"):
        next(ahead.frames(1))


def test_render_ahead_writes_the_environment_on_the_calling_thread_only(small_run,
                                                                        gl_available):
    """C ``setenv`` in one thread while another runs ``getenv`` can crash the process
    (seen: a perception worker's segfault in getenv): a fresh process's GL setup
    (``os.environ`` writes) must happen before the render thread starts, on the caller's."""
    import subprocess
    import sys

    code = f"""
import os, threading, warnings
warnings.simplefilter("ignore")
writes = []
real = os.putenv
def putenv(k, v):
    writes.append(threading.current_thread().name)
    real(k, v)
os.putenv = putenv
from dashtraj.world.recording import Recording
from dashtraj.datasets.frames import RenderAhead
rec = Recording.open({str(small_run.path)!r})
with RenderAhead(rec, [1], 2.0, (160, 90)) as ahead:
    n = sum(1 for _ in ahead.frames(1))
print(n, sorted(set(writes)))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300, check=True).stdout.split()
    assert int(out[0]) > 5
    assert "".join(out[1:]) == "['MainThread']"


def test_sightings_command_takes_the_camera_pipeline(small_run, gl_available, tmp_path, capsys):
    out = tmp_path / "s.csv"
    assert main(["sightings", str(small_run.path), "--detector", "oracle", "--tracker", "sort",
                 "-o", str(out)]) == 0
    rows = read_sightings(out)
    assert rows and {r.observer_id for r in rows} <= {1, 2, 3}
    assert "from" in capsys.readouterr().out
    # without a source flag the oracle is used (the default source); --oracle excludes --detector
    assert main(["sightings", str(small_run.path), "-o", str(tmp_path / "x.csv")]) == 0
    assert "(noise none)" in capsys.readouterr().out
    assert main(["sightings", str(small_run.path), "--oracle", "--detector", "oracle",
                 "-o", str(tmp_path / "y.csv")]) == 2
    assert "cannot be combined" in capsys.readouterr().err
    assert not (tmp_path / "y.csv").exists()


def test_perceive_runs_an_onnx_detector(small_run, gl_available, tmp_path, capsys):
    """``--detector M.onnx`` goes through `YoloDetector` (the shipped model): every detection is
    stored with a class among the 15, a score in (0, 1], a box inside the image, and the truth
    vehicle id of the box it overlaps (or none)."""
    from dashtraj.perception.detect import default_model_path
    from dashtraj.perception.detections import DETECTION_CLASSES

    db_path = tmp_path / "m.db"
    assert main(["perceive", str(small_run.path), "--detector", str(default_model_path()),
                 "--observers", "1", "--every", "1.0", "-q", "-o", str(db_path)]) == 0
    assert "detector.onnx" in capsys.readouterr().out
    with SightingsDB.open(db_path) as db:
        (obs,) = db.observers()
        assert obs["observer_id"] == 1 and obs["complete"] and obs["frames"] == 26
        dets = db.detections()
        assert dets, "the shipped detector found nothing in 26 frames of town01"
        vids = {v["vehicle_id"] for v in small_run.vehicles}
        for d in dets:
            assert 0 <= d.class_id < len(DETECTION_CLASSES)
            assert 0.0 < d.score <= 1.0
            assert 0 <= d.x0 < d.x1 <= 320 and 0 <= d.y0 < d.y1 <= 180
            assert d.truth_vehicle_id is None or d.truth_vehicle_id in vids


def test_smoothed_localizer_rewrites_the_positions_when_the_observer_ends(small_run, small_db,
                                                                          tmp_path):
    """``smoothed`` (the default): the same frames, boxes, tracks and crops as ``tracked``
    (the crops are cut by the forward estimate, ``tracked``'s, while the frame is in
    memory: exactly the detections it puts within 15 m); the observer's last batch
    rewrites positions, map-matched again, and under 20 m they are no worse overall."""
    from dashtraj.perception.pipeline import PerceiveConfig, perceive

    path, _ = small_db
    other = tmp_path / "tracked.db"
    perceive(small_run, other, PerceiveConfig(observers=(1, 3), localizer="tracked"))
    with SightingsDB.open(other) as a, SightingsDB.open(path) as b:
        assert a.run_info()["config"]["localizer"] == "tracked"
        assert b.run_info()["config"]["localizer"] == "smoothed"
        assert a.poses() == b.poses() and a.tracks() == b.tracks() and a.crops() == b.crops()
        da, db_ = a.detections(), b.detections()
        near = {(d.observer_id, d.frame, d.idx) for d in da if d.distance_m <= 15.0}
        assert near == {(c.observer_id, c.frame, c.idx) for c in a.crops()}
        assert [d.x0 for d in da] == [d.x0 for d in db_]
        assert all(d.road_id is not None and d.lane_id != 0 for d in db_)
        moved = [(p, q) for p, q in zip(da, db_, strict=True) if abs(p.x - q.x) > 1e-6]
        assert moved
        cam = {(p.observer_id, p.frame): (p.cam_x, p.cam_y) for p in b.poses()}
        assert all(abs(q.distance_m - np.hypot(q.x - cam[(q.observer_id, q.frame)][0],
                                               q.y - cam[(q.observer_id, q.frame)][1])) < 1e-6
                   for q in db_)
    truth = _truth_xy(small_run)

    def rmse(dets):
        e = [np.hypot(d.x - truth[(d.frame, d.truth_vehicle_id)][0],
                      d.y - truth[(d.frame, d.truth_vehicle_id)][1])
             for d in dets if d.distance_m < 20]
        return float(np.sqrt(np.mean(np.square(e))))

    assert rmse(db_) <= rmse(da) + 1e-9


def test_mapped_localizer_in_perceive_keeps_smoothed_on_lane_positions(small_run, small_db,
                                                                       tmp_path):
    """``mapped`` gets the recording's map in ``perceive``: the same detections as
    ``smoothed``; a box not cut by the left or right image border keeps its bearing (its
    position stays, or moves along its ray onto a lane), and most positions stay."""
    from dashtraj.perception.pipeline import PerceiveConfig, perceive

    path, _ = small_db
    other = tmp_path / "mapped.db"
    perceive(small_run, other, PerceiveConfig(observers=(1, 3), localizer="mapped"))
    with SightingsDB.open(other) as a, SightingsDB.open(path) as b:
        assert a.run_info()["config"]["localizer"] == "mapped"
        da, db_ = a.detections(), b.detections()
        assert [(d.observer_id, d.frame, d.idx) for d in da] == \
            [(d.observer_id, d.frame, d.idx) for d in db_]
        w = small_run.config.camera.width_px
        inside = [p for p, q in zip(da, db_, strict=True) if 1.0 < p.x0 and p.x1 < w - 1.0]
        assert inside and all(
            abs(p.bearing_deg - q.bearing_deg) < 1e-9
            for p, q in zip(da, db_, strict=True) if 1.0 < p.x0 and p.x1 < w - 1.0)
        same = sum(p.x == q.x and p.y == q.y for p, q in zip(da, db_, strict=True))
        assert same >= 0.8 * len(da)


def test_perceive_each_renders_once_for_every_output(small_run, small_db, tmp_path,
                                                     monkeypatch):
    """Two pipelines on the same frames (the error budget's exact boxes and detector model):
    each database is the one `perceive` writes with its config alone, the frames are
    rendered once; outputs whose frames differ are refused before any is made."""
    from dashtraj.perception.detect import default_model_path
    from dashtraj.perception.pipeline import PerceiveConfig, PerceiveError, perceive_each
    from dashtraj.render.scene import Renderer

    path, _ = small_db
    oracle = PerceiveConfig(observers=(1, 3))
    model = PerceiveConfig(observers=(1, 3), detector=str(default_model_path()),
                           tracker="sort", localizer="paper")
    alone = tmp_path / "model_alone.db"
    perceive_each(small_run, [(alone, model)])
    drawn = []
    real = Renderer.render

    def counted(self, *a, **k):
        drawn.append(1)
        return real(self, *a, **k)

    monkeypatch.setattr(Renderer, "render", counted)
    both = [(tmp_path / "oracle.db", oracle), (tmp_path / "model.db", model)]
    summaries = perceive_each(small_run, both)
    frames_drawn = len(drawn)
    _same_content(path, both[0][0])
    _same_content(alone, both[1][0])
    assert [s.frames for s in summaries] == [frames_drawn, frames_drawn]
    assert summaries[1].detections > 0
    with pytest.raises(PerceiveError, match="frames differ"):
        perceive_each(small_run, [(tmp_path / "a.db", oracle),
                                  (tmp_path / "b.db", PerceiveConfig(observers=(1,)))])
    assert not (tmp_path / "a.db").exists() and not (tmp_path / "b.db").exists()
