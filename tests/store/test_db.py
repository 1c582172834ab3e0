"""The sightings database: round trip, bad files, a killed writer, export to CSV."""

from __future__ import annotations

import sqlite3
import subprocess
import sys
import textwrap

import pytest

from dashtraj.cli import main
from dashtraj.store import CropRow, DetectionRow, PoseRow, SightingsDB, StoreError, TrackRow
from dashtraj.trajectory.io import read_sightings


def _rows(observer: int, frames: range):
    poses, dets, crops = [], [], []
    for f in frames:
        t = f * 0.1
        poses.append(PoseRow(observer, f, t, 10.0 + f, 5.0, 0.0, 90.0, 11.0 + f, 5.0, 1.6, 90.0,
                             0.0))
        for i in range(2):
            dets.append(DetectionRow(observer, f, i, t, 7 + i if f > 1 else None, 100.0 + i,
                                     200.0, 150.0, 260.5, 0.9, 1 + 3 * i, ("car", "truck")[i],
                                     "back", 8.5 + i * 10, -3.25, 12.0 + f, 20.0 + i, 0.0, 4, 0,
                                     -1, 33.5 + f, 0.25, 3 + i))
            if i == 0:
                crops.append(CropRow(observer, f, i, bytes([f % 256, i, 255]) * 100, 60, 66))
    tracks = [TrackRow(observer, 7, "car", 0.2, frames[-1] * 0.1, len(frames) - 2, 3),
              TrackRow(observer, 8, "truck", 0.2, frames[-1] * 0.1, len(frames) - 2, 4)]
    return poses, dets, crops, tracks


def _write(path, observers=(1, 2), frames=range(6)):
    written = {}
    with SightingsDB.create(path) as db:
        db.write_run("runs/x", "town01", "ab" * 32, {"width_px": 1280}, {"tracker": "ego"},
                     [(o, "oncoming") for o in observers])
        db.set_meta({"source_sha256": "cd" * 32, "detector_sha256": "oracle"})
        for o in observers:
            rows = _rows(o, frames)
            db.add_frames(*rows)
            db.finish_observer(o)
            written[o] = rows
        db.finish_run()
    return written


def test_round_trip_equals_records_written(tmp_path):
    path = tmp_path / "run.db"
    written = _write(path)
    with SightingsDB.open(path) as db:
        assert db.run_info() == {"recording": "runs/x", "map_name": "town01",
                                 "map_sha256": "ab" * 32, "camera": {"width_px": 1280},
                                 "config": {"tracker": "ego"}, "complete": True}
        assert db.meta() == {"format": "dashtraj-sightings", "schema_version": "3",
                             "source_sha256": "cd" * 32, "detector_sha256": "oracle"}
        assert [o["frames"] for o in db.observers()] == [6, 6]
        assert all(o["complete"] for o in db.observers())
        for o, (poses, dets, _crops, _tracks) in written.items():
            assert db.poses(o) == poses
            assert db.detections(o) == dets
        assert db.crops() == written[1][2] + written[2][2]
        assert db.tracks() == written[1][3] + written[2][3]
        s = db.sightings(vehicle=3)
        # detections with a confirmed track only (frames 2..5), observer pose = camera pose
        assert len(s) == 2 * 4
        assert {(x.observer_id, x.track_id) for x in s} == {(1, 7), (2, 7)}
        first = next(x for x in s if x.observer_id == 1)
        assert (first.t, first.observer_x, first.observer_yaw, first.x, first.y) == (
            0.2, 13.0, 90.0, 14.0, 20.0)
        assert (first.distance, first.bearing, first.vehicle_class) == (8.5, -3.25, "car")
        assert len(db.sightings(max_distance_m=10.0)) == 8
        assert len(db.sightings(tracked_only=False)) == 24
        assert len(db.sightings(sample_s=0.25)) == 2 * 2 * 2  # t = 0.2, 0.5 per track


def test_export_cli_writes_todays_csv(tmp_path, capsys):
    path = tmp_path / "run.db"
    _write(path)
    out = tmp_path / "s.csv"
    assert main(["sightings", "export", str(path), "-o", str(out), "--vehicle", "4",
                 "--sample", "0", "--max-distance", "30"]) == 0
    rows = read_sightings(out)
    with SightingsDB.open(path) as db:
        assert rows == db.sightings(vehicle=4, max_distance_m=30.0)
    assert len(rows) == 8 and {r.vehicle_class for r in rows} == {"truck"}
    # refused without --overwrite, replaced whole with it
    assert main(["sightings", "export", str(path), "-o", str(out), "--vehicle", "all"]) == 2
    assert "exists" in capsys.readouterr().err
    assert main(["sightings", "export", str(path), "-o", str(out), "--vehicle", "all",
                 "--overwrite", "--max-distance", "100", "--sample", "0"]) == 0
    assert len(read_sightings(out)) == 16


def test_foreign_and_truncated_files_are_clear_errors(tmp_path, capsys):
    text = tmp_path / "notes.db"
    text.write_text("hello, not a database\n")
    with pytest.raises(StoreError, match="not an SQLite file"):
        SightingsDB.open(text)
    other = tmp_path / "other.db"
    con = sqlite3.connect(other)
    con.execute("CREATE TABLE t (a)")
    con.commit()
    con.close()
    with pytest.raises(StoreError, match="not a dashtraj sightings database"):
        SightingsDB.open(other)
    good = tmp_path / "run.db"
    _write(good, frames=range(300))
    data = good.read_bytes()
    cut = tmp_path / "cut.db"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(StoreError, match=r"truncated or corrupt|corrupt"):
        db = SightingsDB.open(cut)
        db.detections()
    with pytest.raises(StoreError, match="does not exist"):
        SightingsDB.open(tmp_path / "missing.db")
    assert main(["sightings", "export", str(cut), "-o", str(tmp_path / "s.csv")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("dashtraj: error:") and "cut.db" in err and err.count("\n") == 1


def test_killed_writer_leaves_committed_frames_readable(tmp_path):
    path = tmp_path / "run.db"
    script = textwrap.dedent(f"""
        import os, sys
        sys.path.insert(0, {str(tmp_path)!r})
        from dashtraj.store import SightingsDB
        from test_rows import rows
        db = SightingsDB.create({str(path)!r})
        db.write_run("r", None, None, {{}}, {{}}, [(1, None)])
        db.add_frames(*rows(1, range(0, 5)))
        db.add_frames(*rows(1, range(5, 9)))
        db.conn.execute("BEGIN")
        db.conn.execute("DELETE FROM poses")  # an uncommitted change, then a hard kill
        os._exit(9)
    """)
    helper = tmp_path / "test_rows.py"
    helper.write_text("from store_rows import _rows as rows\n")
    (tmp_path / "store_rows.py").write_text(
        open(__file__, encoding="utf-8").read().split("def _write")[0])
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert res.returncode == 9, res.stderr
    assert (tmp_path / "run.db-wal").exists()  # the writer never closed
    with SightingsDB.open(path) as db:
        assert [p.frame for p in db.poses(1)] == list(range(9))
        assert len(db.detections(1)) == 18
        assert db.run_info()["complete"] is False
        assert db.observers()[0]["complete"] is False


def test_a_finished_database_is_one_file_that_reading_leaves_alone(tmp_path):
    path = tmp_path / "run.db"
    _write(path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.db"]
    before = path.read_bytes()
    with SightingsDB.open(path) as db:
        assert len(db.detections(1)) == 12
    out = tmp_path / "s.csv"
    assert main(["sightings", "export", str(path), "-o", str(out), "--vehicle", "7"]) == 0
    # no -wal / -shm left beside the user's file by the readers, and not a byte changed
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.db", "s.csv"]
    assert path.read_bytes() == before
    con = sqlite3.connect(path)
    assert con.execute("PRAGMA journal_mode").fetchone()[0] == "delete"
    con.close()


def test_a_reader_open_while_the_writer_closes_keeps_the_file_in_wal_mode(tmp_path):
    path = tmp_path / "run.db"
    db = SightingsDB.create(path)
    db.write_run("r", None, None, {}, {}, [(1, None)])
    db.add_frames(*_rows(1, range(3)))
    with SightingsDB.open(path) as reader:
        db.close()  # SQLite refuses to leave WAL mode while the reader is open: no error
        assert len(reader.detections(1)) == 6
    with SightingsDB.open(path) as again:
        assert [p.frame for p in again.poses(1)] == [0, 1, 2]


def test_create_refuses_an_existing_file_and_reads_are_read_only(tmp_path):
    path = tmp_path / "run.db"
    _write(path)
    with pytest.raises(StoreError, match="exists"):
        SightingsDB.create(path)
    with SightingsDB.open(path) as db, pytest.raises(StoreError, match="read-only"):
        db.finish_run()


def test_location_updates_rewrite_positions_in_the_batch_or_refuse_it_whole(tmp_path):
    from dataclasses import replace

    from dashtraj.store import LocationUpdate

    path = tmp_path / "run.db"
    with SightingsDB.create(path) as db:
        db.write_run("runs/x", "town01", "ab" * 32, {}, {}, [(1, None)])
        poses, dets, crops, tracks = _rows(1, range(4))
        db.add_frames(poses[:2], [d for d in dets if d.frame < 2], crops[:2], tracks)
        rest = [d for d in dets if d.frame >= 2]
        up = [LocationUpdate(1, 0, 1, 30.0, 4.5, 40.0, 41.0, 0.5, 9, 0, 1, 2.5, -0.1),
              LocationUpdate(1, 3, 0, 31.0, -4.5, 50.0, 51.0, 0.0, None, None, None, None,
                             None)]
        bad = [*up, LocationUpdate(1, 9, 0, 1.0, 0.0, 0.0, 0.0, 0.0, 1, 0, 1, 0.0, 0.0)]
        with pytest.raises(StoreError, match="not in the file"):
            db.add_frames(poses[2:], rest, crops[2:], tracks, bad)
        assert db.count("poses") == 2 and db.count("detections") == 4  # rolled back whole
        db.add_frames(poses[2:], rest, crops[2:], tracks, up)
        got = {(d.frame, d.idx): d for d in db.detections(1)}
    want = {(d.frame, d.idx): d for d in dets}
    want[(0, 1)] = replace(want[(0, 1)], distance_m=30.0, bearing_deg=4.5, x=40.0, y=41.0,
                           z=0.5, road_id=9, section_id=0, lane_id=1, s=2.5, lateral_m=-0.1)
    want[(3, 0)] = replace(want[(3, 0)], distance_m=31.0, bearing_deg=-4.5, x=50.0, y=51.0,
                           z=0.0, road_id=None, section_id=None, lane_id=None, s=None,
                           lateral_m=None)
    assert got == want
