"""The sightings database in PostgreSQL (a real server: the pgserver wheel's PostgreSQL 16):
the same repository as an SQLite file reads back the same records; bad targets and foreign
schemas are clear errors; a reader cannot write."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
from test_db import _rows, _write

from dashtraj.cli import main
from dashtraj.store import LocationUpdate, SightingsDB, StoreError
from dashtraj.store.backend import parse_url


def _everything(db) -> dict:
    """Every read of the repository, for comparing two databases."""
    return {"run": db.run_info(), "meta": db.meta(), "observers": db.observers(),
            "poses": db.poses(),
            "poses_2": db.poses(2), "detections": db.detections(), "tracks": db.tracks(),
            "crops": db.crops(), "some_crops": db.crops([(2, 3, 0), (1, 0, 0), (9, 9, 9)]),
            "counts": [db.count(t) for t in ("poses", "detections", "tracks", "crops",
                                             "embeddings")],
            "sightings": db.sightings(), "all": db.sightings(tracked_only=False),
            "near": db.sightings(vehicle=4, max_distance_m=30.0),
            "sampled": db.sightings(sample_s=0.25, tracked_only=False)}


def test_postgres_reads_back_what_sqlite_reads_back(pg_url, tmp_path):
    written_pg = _write(pg_url)
    written_file = _write(tmp_path / "run.db")
    assert written_pg == written_file
    with SightingsDB.open(pg_url) as pg, SightingsDB.open(tmp_path / "run.db") as lite:
        a, b = _everything(pg), _everything(lite)
        assert a == b
        assert len(a["detections"]) == 24 and len(a["all"]) == 24 and len(a["sampled"]) == 16
        assert pg.path == parse_url(pg_url).display and "schema=" in pg.path


def test_embeddings_round_trip_and_refusals(pg_url):
    _write(pg_url)
    rng = np.random.default_rng(0)
    with SightingsDB.open(pg_url, writable=True) as db:
        keys = [(c.observer_id, c.frame, c.idx) for c in db.crops()]
        assert db.count_missing_embeddings("ab" * 32) == len(keys) == 12
        vec = rng.normal(size=(len(keys), 8)).astype(np.float32)
        assert db.add_embeddings("m.onnx", "ab" * 32, keys, vec) == 12
        assert db.add_embeddings("m.onnx", "ab" * 32, keys, vec) == 0  # idempotent
        assert db.crops_missing_embedding("ab" * 32) == []
        page = db.crops_missing_embedding("cd" * 32, limit=5, after=(1, 2, 0))
        assert [(c.observer_id, c.frame) for c in page] == [(1, 3), (1, 4), (1, 5), (2, 0),
                                                            (2, 1)]
        e = db.embeddings("ab" * 32)
        assert np.array_equal(e.vectors, vec) and e.keys() == keys
        assert e.track_id.tolist()[:3] == [-1, -1, 7]
        assert [(m.model, m.dim, m.count) for m in db.embedding_models()] == [("m.onnx", 8, 12)]
        with pytest.raises(StoreError, match="a key has no crop"):
            db.add_embeddings("m.onnx", "cd" * 32, [(1, 0, 1)], vec[:1])
        with pytest.raises(StoreError, match="8-d embeddings"):
            db.add_embeddings("m.onnx", "ab" * 32, keys[:1], vec[:1, :4])
        assert db.count("embeddings") == 12  # the refused batches left nothing


def test_a_batch_with_a_bad_update_is_refused_whole(pg_url):
    with SightingsDB.create(pg_url) as db:
        db.write_run("runs/x", None, None, {}, {}, [(1, None)])
        poses, dets, crops, tracks = _rows(1, range(3))
        bad = LocationUpdate(1, 7, 0, 1.0, 2.0, 3.0, 4.0, 0.0, None, None, None, None, None)
        with pytest.raises(StoreError, match="names a detection that is not in the file"):
            db.add_frames(poses, dets, crops, tracks, [bad])
        assert db.count("poses") == 0 and db.observers()[0]["frames"] == 0


def test_bad_targets_and_foreign_schemas_are_clear_errors(pg_url, pg_server, capsys):
    import psycopg

    with pytest.raises(StoreError, match="no such schema"):
        SightingsDB.open(pg_url)
    with pytest.raises(StoreError, match="schema 'Bad-Name' must be lower-case"):
        SightingsDB.open(pg_url.replace("schema=", "schema=Bad-Name&x="))
    target = parse_url(pg_url)
    with psycopg.connect(target.conninfo, autocommit=True) as c:
        c.execute(f'CREATE SCHEMA "{target.schema}"')
        c.execute(f'CREATE TABLE "{target.schema}".notes (a TEXT)')
    with pytest.raises(StoreError, match="a PostgreSQL schema but not a dashtraj sightings"):
        SightingsDB.open(pg_url)
    with pytest.raises(StoreError, match="exists; a sightings database is written whole"):
        SightingsDB.create(pg_url)
    assert main(["sightings", "export", pg_url, "-o", "/nonexistent/s.csv"]) == 2
    err = capsys.readouterr().err
    assert "not a dashtraj sightings database" in err and err.count("\n") == 1
    # the server refuses what it cannot reach, named without the password
    bad = "postgresql://someone:secret@/nowhere?host=/nonexistent&schema=x"
    with pytest.raises(StoreError, match=r"someone:\*\*\*@.*cannot connect") as exc:
        SightingsDB.open(bad)
    assert "secret" not in str(exc.value)


def test_readers_cannot_write_and_the_driver_is_named_when_missing(pg_url, monkeypatch):
    import psycopg

    _write(pg_url)
    with SightingsDB.open(pg_url) as db:
        with pytest.raises(StoreError, match="opened read-only"):
            db.finish_run()
        with pytest.raises(psycopg.errors.ReadOnlySqlTransaction):
            db.conn.execute("DELETE FROM poses")
        assert db.count("poses") == 12
    monkeypatch.setitem(sys.modules, "psycopg", None)
    with pytest.raises(StoreError, match=r"pip install 'dashtraj\[postgres\]'"):
        SightingsDB.open(pg_url)


def _embed(path) -> np.ndarray:
    with SightingsDB.open(path, writable=True) as db:
        keys = [(c.observer_id, c.frame, c.idx) for c in db.crops()]
        vec = np.random.default_rng(1).normal(size=(len(keys), 16)).astype(np.float32)
        db.add_embeddings("m.onnx", "ef" * 32, keys, vec)
    return vec


def test_sightings_copy_file_to_postgres_and_back_keeps_every_row(pg_url, tmp_path, capsys,
                                                                 monkeypatch):
    src, back = tmp_path / "run.db", tmp_path / "back.db"
    _write(src)
    vec = _embed(src)
    assert main(["sightings-copy", str(src), "-o", pg_url, "--json"]) == 0
    counts = json.loads(capsys.readouterr().out)
    assert {k: counts[k] for k in ("poses", "detections", "tracks", "crops", "embeddings")} == {
        "poses": 12, "detections": 24, "tracks": 4, "crops": 12, "embeddings": 12}
    assert main(["sightings-copy", pg_url, "-o", str(back)]) == 0
    with SightingsDB.open(src) as a, SightingsDB.open(pg_url) as b, SightingsDB.open(back) as c:
        assert _everything(a) == _everything(b) == _everything(c)
        for db in (b, c):
            assert np.array_equal(db.embeddings("ef" * 32).vectors, vec)
    # refused without --overwrite; a copy that fails leaves the old run and no partial schema
    assert main(["sightings-copy", str(src), "-o", pg_url]) == 2
    assert "exists; pass --overwrite" in capsys.readouterr().err

    def fail(self, *a, **k):
        raise StoreError("disk full (simulated)")

    other = tmp_path / "other.db"
    _write(other, observers=(5,))
    monkeypatch.setattr(SightingsDB, "finish_run", fail)  # after every row is written
    assert main(["sightings-copy", str(other), "-o", pg_url, "--overwrite"]) == 2
    assert "disk full" in capsys.readouterr().err
    with SightingsDB.open(pg_url) as db:
        assert [o["observer_id"] for o in db.observers()] == [1, 2]
    target = parse_url(pg_url)
    with SightingsDB.open(pg_url) as db:
        left = db.conn.execute("SELECT schema_name FROM information_schema.schemata WHERE "
                               "schema_name LIKE %s", (target.schema + "%",)).fetchall()
    assert left == [(target.schema,)]


def test_two_writers_adding_the_same_vectors_at_once_add_each_once(pg_url):
    import threading
    from concurrent.futures import ThreadPoolExecutor

    _write(pg_url)
    with SightingsDB.open(pg_url) as db:
        keys = [(c.observer_id, c.frame, c.idx) for c in db.crops()]
    vec = np.random.default_rng(2).normal(size=(len(keys), 8)).astype(np.float32)
    start = threading.Barrier(2)

    def embed(part):
        with SightingsDB.open(pg_url, writable=True) as db:
            start.wait()
            return db.add_embeddings("m.onnx", "ab" * 32, [keys[i] for i in part], vec[part])

    with ThreadPoolExecutor(2) as ex:  # overlapping halves, each in its own connection
        added = list(ex.map(embed, [list(range(0, 9)), list(range(3, 12))]))
    assert sum(added) == 12 and min(added) >= 3
    with SightingsDB.open(pg_url) as db:
        assert np.array_equal(db.embeddings("ab" * 32).vectors, vec)
