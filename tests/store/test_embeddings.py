"""The embeddings table of the sightings database: round trip, idempotence, models side by
side, refusals, paging, and the upgrade of a version-1 file."""

from __future__ import annotations

import sqlite3

import numpy as np
import pytest

from dashtraj.store import (
    SCHEMA_VERSION,
    CropRow,
    DetectionRow,
    EmbeddingModel,
    PoseRow,
    SightingsDB,
    StoreError,
)

SHA_A = "a" * 64
SHA_B = "b" * 64


def _det(o: int, f: int, i: int, track: int | None, truth: int | None) -> DetectionRow:
    return DetectionRow(o, f, i, f * 0.1, track, 10.0 * i, 20.0, 10.0 * i + 30.0, 60.5, 0.9, 1,
                        ("car", "truck")[i % 2], "back", 7.5 + i, 1.0, 0.0, 0.0, 0.0, None, None,
                        None, None, None, truth)


def _write(path, observers=(1, 2), frames=range(4)):
    """Two observers, three detections a frame: idx 0 and 1 with crops (tracks 5 and 6;
    track 5 unconfirmed on frame 0), idx 2 without a crop."""
    with SightingsDB.create(path) as db:
        db.write_run("runs/x", "town01", None, {}, {}, [(o, None) for o in observers])
        for o in observers:
            poses = [PoseRow(o, f, f * 0.1, 0, 0, 0, 0, 0, 0, 1.6, 0, 0) for f in frames]
            dets = [_det(o, f, i, (5 + i if (f > 0 or i == 1) else None) if i < 2 else 9,
                         100 + i) for f in frames for i in range(3)]
            crops = [CropRow(o, f, i, b"\xff\xd8" + bytes([o, f, i]), 30, 40) for f in frames
                     for i in range(2)]
            db.add_frames(poses, dets, crops)


def _vectors(n: int, dim: int, seed: int) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(n, dim)).astype(np.float32)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_round_trip_with_detection_columns(tmp_path):
    path = tmp_path / "run.db"
    _write(path)
    with SightingsDB.open(path, writable=True) as db:
        crops = db.crops()
        assert len(crops) == 16 and db.count_missing_embeddings(SHA_A) == 16
        keys = [(c.observer_id, c.frame, c.idx) for c in crops]
        vec = _vectors(16, 512, 0)
        assert db.add_embeddings("m.onnx", SHA_A, keys, vec) == 16
    with SightingsDB.open(path) as db:
        assert db.embedding_models() == [EmbeddingModel("m.onnx", SHA_A, 512, 16)]
        assert db.count("embeddings") == 16
        e = db.embeddings(SHA_A)
        assert (e.model, e.model_sha256, e.dim, len(e)) == ("m.onnx", SHA_A, 512, 16)
        assert e.keys() == keys
        assert np.array_equal(e.vectors, vec) and e.vectors.dtype == np.float32
        # observer 1, frame 0, idx 0: unconfirmed (-1); idx 1: track 6
        assert e.track_id[:4].tolist() == [-1, 6, 5, 6]
        assert e.t[:4].tolist() == [0.0, 0.0, 0.1, 0.1]
        assert e.box[1].tolist() == [10.0, 20.0, 40.0, 60.5]
        assert e.vehicle_class[:2] == ("car", "truck")
        assert e.distance_m[:2].tolist() == [7.5, 8.5]
        assert e.truth_vehicle_id[:2].tolist() == [100, 101]
        tr = db.embeddings(SHA_A, observer_id=2, track_id=5)
        assert tr.keys() == [(2, 1, 0), (2, 2, 0), (2, 3, 0)]
        assert np.array_equal(tr.vectors, vec[[10, 12, 14]])
        assert len(db.embeddings(SHA_A, track_id=9)) == 0  # a track without crops
        with pytest.raises(StoreError, match=r"no embeddings of model sha256 bbbbbbbbbbbb.*"
                                             r"models: m.onnx \(aaaaaaaaaaaa"):
            db.embeddings(SHA_B)


def test_idempotent_and_models_side_by_side(tmp_path):
    path = tmp_path / "run.db"
    _write(path)
    with SightingsDB.open(path, writable=True) as db:
        first = db.crops_missing_embedding(SHA_A, limit=5)
        assert [(c.observer_id, c.frame, c.idx) for c in first] == [
            (1, 0, 0), (1, 0, 1), (1, 1, 0), (1, 1, 1), (1, 2, 0)]
        page2 = db.crops_missing_embedding(SHA_A, limit=3, after=(1, 2, 0))
        assert [(c.observer_id, c.frame, c.idx) for c in page2] == [(1, 2, 1), (1, 3, 0),
                                                                    (1, 3, 1)]
        keys = [(c.observer_id, c.frame, c.idx) for c in first]
        v = _vectors(5, 8, 1)
        assert db.add_embeddings("m.onnx", SHA_A, keys, v) == 5
        assert db.add_embeddings("m.onnx", SHA_A, keys, _vectors(5, 8, 2)) == 0  # kept
        assert db.count_missing_embeddings(SHA_A) == 11
        assert db.crops_missing_embedding(SHA_A)[0].jpeg == b"\xff\xd8" + bytes([1, 2, 1])
        # another model: its own rows, its own dim
        assert db.count_missing_embeddings(SHA_B) == 16
        assert db.add_embeddings("n.onnx", SHA_B, keys[:2], _vectors(2, 4, 3)) == 2
        assert db.embedding_models() == [EmbeddingModel("m.onnx", SHA_A, 8, 5),
                                         EmbeddingModel("n.onnx", SHA_B, 4, 2)]
        assert np.array_equal(db.embeddings(SHA_A).vectors, v)  # the first write stands
        assert db.crops(keys=[(2, 3, 1), (1, 0, 0), (7, 7, 7)]) == [
            c for c in db.crops() if (c.observer_id, c.frame, c.idx) in {(2, 3, 1), (1, 0, 0)}]


def test_refusals_name_the_problem(tmp_path):
    path = tmp_path / "run.db"
    _write(path)
    with SightingsDB.open(path) as db, pytest.raises(StoreError, match="read-only"):
        db.add_embeddings("m", SHA_A, [(1, 0, 0)], _vectors(1, 8, 0))
    with SightingsDB.open(path, writable=True) as db:
        db.add_embeddings("m", SHA_A, [(1, 0, 0)], _vectors(1, 8, 0))
        with pytest.raises(StoreError, match=r"holds 8-d embeddings of model m .* are 16-d"):
            db.add_embeddings("m", SHA_A, [(1, 0, 1)], _vectors(1, 16, 0))
        with pytest.raises(StoreError, match="a key has no crop"):
            db.add_embeddings("m", SHA_A, [(1, 0, 1), (1, 0, 2)], _vectors(2, 8, 0))
        with pytest.raises(StoreError, match="NaN or infinite"):
            db.add_embeddings("m", SHA_A, [(1, 0, 1)], np.full((1, 8), np.nan))
        with pytest.raises(StoreError, match=r"2 keys and vectors of shape \(1, 8\)"):
            db.add_embeddings("m", SHA_A, [(1, 0, 1), (1, 1, 0)], _vectors(1, 8, 0))
        assert db.count("embeddings") == 1  # nothing of a refused batch was written


def test_version_1_file_reads_and_upgrades(tmp_path):
    path = tmp_path / "v1.db"
    _write(path)
    con = sqlite3.connect(path)  # the file as dashtraj with schema version 1 wrote it
    con.execute("DROP TABLE embeddings")
    con.execute("ALTER TABLE detections DROP COLUMN depicted_vehicle_id")
    con.execute("UPDATE meta SET value = '1' WHERE key = 'schema_version'")
    con.commit()
    con.close()
    with SightingsDB.open(path) as db:
        assert db.embedding_models() == [] and db.count("embeddings") == 0
        assert db.count_missing_embeddings(SHA_A) == 16
        assert len(db.crops_missing_embedding(SHA_A, limit=4)) == 4
    con = sqlite3.connect(path)
    assert con.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone() == ("1",)
    con.close()
    with SightingsDB.open(path, writable=True) as db:
        assert db.add_embeddings("m", SHA_A, [(1, 0, 0)], _vectors(1, 8, 0)) == 1
    con = sqlite3.connect(path)
    assert con.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone() == (
        str(SCHEMA_VERSION),)
    con.close()
    with SightingsDB.open(path) as db:
        assert db.count("embeddings") == 1 and len(db.detections()) == 24


def test_version_2_file_reads_without_depicted_ids_and_upgrades(tmp_path):
    path = tmp_path / "v2.db"
    _write(path)
    con = sqlite3.connect(path)  # schema version 2: no detections.depicted_vehicle_id
    con.execute("ALTER TABLE detections DROP COLUMN depicted_vehicle_id")
    con.execute("UPDATE meta SET value = '2' WHERE key = 'schema_version'")
    con.commit()
    con.close()
    with SightingsDB.open(path) as db:
        dets = db.detections()
        assert len(dets) == 24 and all(d.depicted_vehicle_id is None for d in dets)
    with SightingsDB.open(path, writable=True) as db:
        assert db.version == SCHEMA_VERSION == 3
        assert all(d.depicted_vehicle_id is None for d in db.detections())
    con = sqlite3.connect(path)
    assert "depicted_vehicle_id" in [r[1] for r in con.execute("PRAGMA table_info(detections)")]
    con.close()


def test_newer_schema_is_refused(tmp_path):
    path = tmp_path / "run.db"
    _write(path)
    con = sqlite3.connect(path)
    con.execute("UPDATE meta SET value = ? WHERE key = 'schema_version'",
                (str(SCHEMA_VERSION + 1),))
    con.commit()
    con.close()
    for writable in (False, True):
        with pytest.raises(StoreError, match="is newer than this dashtraj reads"):
            SightingsDB.open(path, writable=writable)
