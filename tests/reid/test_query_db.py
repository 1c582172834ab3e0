"""`dashtraj reid embed DB` and `dashtraj reid query DB` on a real perception run: crops of a
short town01 recording (oracle detector, rendered frames) embedded with the shipped model,
then tracks ranked against a track seen by another observer, against an image, and the
gallery search checked against a brute force on the database's vectors."""

from __future__ import annotations

import itertools
import json
import shutil
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest

from dashtraj.cli import main
from dashtraj.store import SightingsDB

pytest.importorskip("faiss")


@pytest.fixture(scope="module")
def run_db(tmp_path_factory, gl_available):
    """30 s on town01, seed 2, 4 observers, 10 agents, 320 x 180 camera, perceived with
    the oracle detector: 16 tracks, 14 of them with crops (≈220 crops)."""
    from dashtraj.perception.pipeline import PerceiveConfig, perceive
    from dashtraj.world.camera import CameraSpec
    from dashtraj.world.recording import Recording, RunConfig, simulate

    root = tmp_path_factory.mktemp("reiddb")
    cfg = RunConfig(map="town01", seed=2, duration_s=30.0, n_observers=4, n_agents=10,
                    camera=CameraSpec(width_px=320, height_px=180))
    simulate(cfg, root / "run")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rec = Recording.open(root / "run")
    perceive(rec, root / "run.db", PerceiveConfig())
    return root / "run.db"


@pytest.fixture(scope="module")
def embedded(run_db, tmp_path_factory):
    """A copy of the run's database with every crop embedded by the shipped model."""
    path = tmp_path_factory.mktemp("embedded") / "run.db"
    shutil.copy(run_db, path)
    assert main(["reid", "embed", str(path), "-q"]) == 0
    return path


def _sha(db) -> str:
    (m,) = db.embedding_models()
    return m.model_sha256


def _json(capsys) -> dict:
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def test_embed_adds_every_crop_once_and_another_model_its_own(run_db, tmp_path, capsys):
    import onnxruntime as ort

    from dashtraj.reid.embed import ReidEmbedder, shipped_model_path

    path = tmp_path / "run.db"
    shutil.copy(run_db, path)
    with SightingsDB.open(path) as db:
        n = db.count("crops")
    assert n > 150
    assert main(["reid", "embed", str(path), "--batch", "50", "--json"]) == 0
    first = _json(capsys)
    dim = ReidEmbedder(threads=1).dim
    assert (first["crops"], first["already"], first["added"], first["dim"]) == (n, 0, n, dim)
    assert first["batches"] == -(-n // 50)
    assert main(["reid", "embed", str(path), "--json"]) == 0  # a rerun adds nothing
    again = _json(capsys)
    assert (again["already"], again["added"], again["batches"]) == (n, 0, 0)
    # another model file (onnxruntime's optimised copy of the shipped graph: other bytes,
    # other sha256, the same function) adds its own rows beside the first model's
    other = tmp_path / "optimised.onnx"
    so = ort.SessionOptions()
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_BASIC
    so.optimized_model_filepath = str(other)
    ort.InferenceSession(str(shipped_model_path()), so, providers=["CPUExecutionProvider"])
    assert main(["reid", "embed", str(path), "--model", str(other), "--json"]) == 0
    second = _json(capsys)
    assert second["added"] == n and second["model_sha256"] != first["model_sha256"]
    with SightingsDB.open(path) as db:
        models = db.embedding_models()
        assert sorted(m.count for m in models) == [n, n] and db.count("embeddings") == 2 * n
        a = db.embeddings(first["model_sha256"])
        b = db.embeddings(second["model_sha256"])
    assert a.keys() == b.keys()
    np.testing.assert_allclose(a.vectors, b.vectors, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(a.vectors, axis=1), 1.0, atol=1e-5)


def test_killed_embed_keeps_whole_batches_and_a_rerun_completes(run_db, embedded, tmp_path,
                                                                capsys):
    path = tmp_path / "run.db"
    shutil.copy(run_db, path)
    # a hard kill (no cleanup, no close) right after the third batch was committed, while
    # the fourth is being embedded
    script = textwrap.dedent(f"""
        import os
        from dashtraj.reid.database import embed_database
        from dashtraj.reid.embed import ReidEmbedder
        from dashtraj.store import SightingsDB
        calls = []
        def progress(n):
            calls.append(n)
            if len(calls) == 3:
                os._exit(9)
        db = SightingsDB.open({str(path)!r}, writable=True)
        embed_database(db, ReidEmbedder(), batch_size=16, progress=progress)
    """)
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert res.returncode == 9, res.stderr
    with SightingsDB.open(path) as db:  # integrity-checked on open
        assert db.count("embeddings") == 48
        n = db.count("crops")
        part = db.embeddings(_sha(db))
        assert part.keys() == [(c.observer_id, c.frame, c.idx) for c in db.crops()][:48]
    assert main(["reid", "embed", str(path), "--json"]) == 0
    rerun = _json(capsys)
    assert (rerun["already"], rerun["added"]) == (48, n - 48)
    with SightingsDB.open(path) as db, SightingsDB.open(embedded) as ref:
        done, whole = db.embeddings(_sha(db)), ref.embeddings(_sha(ref))
    assert done.keys() == whole.keys()
    np.testing.assert_allclose(done.vectors, whole.vectors, atol=1e-5)


def test_gallery_search_equals_brute_force_on_the_database_vectors(embedded):
    from dashtraj.reid.gallery import Gallery, brute_force_search
    from dashtraj.reidentify.rank import query_vector, rank_tracks

    with SightingsDB.open(embedded) as db:
        e = db.embeddings(_sha(db))
    g = Gallery(e.vectors.shape[1], metric="ip")
    g.add(e.vectors, ids=np.arange(len(e)) + 1000)
    s, i = g.search(e.vectors[:40], k=15)
    bs, bi = brute_force_search(e.vectors, e.vectors[:40], 15, "ip", np.arange(len(e)) + 1000)
    np.testing.assert_allclose(s, bs, atol=1e-5)
    np.testing.assert_array_equal(i[:, 0], np.arange(40) + 1000)  # each crop finds itself
    assert (i == bi).mean() > 0.99  # float ties may swap neighbours in the last digit
    for q in range(len(e)):  # every track's ranking: faiss flat == numpy brute force
        if e.track_id[q] < 0:
            continue
        rows = np.flatnonzero((e.observer_id == e.observer_id[q]) & (e.track_id == e.track_id[q]))
        ex = (int(e.observer_id[q]), int(e.track_id[q]))
        a = rank_tracks(query_vector(e.vectors[rows]), e, k=20, exclude=ex, aggregate="mean")
        b = rank_tracks(query_vector(e.vectors[rows]), e, k=20, exclude=ex, aggregate="mean",
                        backend="numpy")
        assert [(t.observer_id, t.track_id) for t in a.tracks] == [
            (t.observer_id, t.track_id) for t in b.tracks]
        np.testing.assert_allclose([t.distance for t in a.tracks],
                                   [t.distance for t in b.tracks], atol=1e-5)
        assert ex not in {(t.observer_id, t.track_id) for t in a.tracks}
        # an independent brute force: every track's crops, 1 - q.g, aggregated, sorted
        qv = query_vector(e.vectors[rows]).astype(np.float64)
        for agg, fn in (("mean", np.mean), ("min", np.min),
                        ("kmin-mean", lambda d: np.sort(d)[:(len(d) + 1) // 2].mean())):
            ref = sorted((float(fn(1 - e.vectors[m].astype(np.float64) @ qv)), o, t)
                         for o, t in {(int(o), int(t)) for o, t in zip(
                             e.observer_id, e.track_id, strict=True) if t >= 0} - {ex}
                         for m in [(e.observer_id == o) & (e.track_id == t)])
            got = rank_tracks(qv, e, k=5, exclude=ex, aggregate=agg).tracks
            assert [(t.observer_id, t.track_id) for t in got] == [r[1:] for r in ref[:5]], agg
            np.testing.assert_allclose([t.distance for t in got], [r[0] for r in ref[:5]],
                                       atol=1e-5)


def _partner_ranks(e, aggregate):
    """For each track whose vehicle another observer also tracked: the best rank of such a
    track when querying with it, the gallery size and the chance expectation of that rank."""
    from dashtraj.reidentify.rank import query_vector, rank_tracks

    tracks = {}
    for i in np.flatnonzero(e.track_id >= 0):
        tracks.setdefault((int(e.observer_id[i]), int(e.track_id[i])), []).append(i)
    truth = {k: int(np.bincount(e.truth_vehicle_id[v]).argmax()) for k, v in tracks.items()}
    out = []
    for k, rows in tracks.items():
        partners = {o for o in tracks if o[0] != k[0] and truth[o] == truth[k]}
        if not partners:
            continue
        r = rank_tracks(query_vector(e.vectors[rows]), e, k=len(tracks), aggregate=aggregate,
                        exclude=k)
        best = min(t.rank for t in r.tracks if (t.observer_id, t.track_id) in partners)
        n = len(tracks) - 1  # the best of m partners among n is at (n + 1) / (m + 1) by chance
        out.append((k, best, n, (n + 1) / (len(partners) + 1)))
    return out


def test_track_query_finds_the_vehicle_seen_by_another_observer(embedded, capsys, tmp_path):
    from dashtraj.reidentify.rank import DEFAULT_AGGREGATE

    with SightingsDB.open(embedded) as db:
        e = db.embeddings(_sha(db))
    res = _partner_ranks(e, DEFAULT_AGGREGATE)
    assert len(res) >= 5 and min(n for _, _, n, _ in res) >= 8
    # The shipped model is under-trained (55 % rank-1 on the ring query set); what it
    # guarantees here: another observer's track of the query's vehicle within the top 5 of
    # the 10 other tracks, and a mean best rank at least one place better than chance
    # (measured with today's vehicle meshes: 1.8 against 4.6 by chance over 5 queries,
    # worst 3).
    assert max(best for _, best, _, _ in res) <= 5
    mean_best = np.mean([best for _, best, _, _ in res])
    assert mean_best <= np.mean([c for _, _, _, c in res]) - 1.0, res
    # the CLI: the target (vehicle 0) seen by observer 1, queried with k = 3
    (trk,) = {int(t) for t, o, v in zip(e.track_id, e.observer_id, e.truth_vehicle_id,
                                         strict=True) if o == 1 and v == 0 and t >= 0}
    sheet = tmp_path / "sheet.png"
    assert main(["reid", "query", str(embedded), "--track", str(trk), "--observer", "1",
                 "--k", "3", "--json", "-o", str(sheet)]) == 0
    out = _json(capsys)
    assert out["query"]["truth_vehicle_id"] == 0 and out["aggregate"] == DEFAULT_AGGREGATE
    assert out["query"]["crops"] == int(np.sum((e.observer_id == 1) & (e.track_id == trk)))
    ranked = out["results"]
    assert [r["rank"] for r in ranked] == [1, 2, 3]
    assert all(a["distance"] <= b["distance"] for a, b in itertools.pairwise(ranked))
    assert (1, trk) not in {(r["observer_id"], r["track_id"]) for r in ranked}
    assert any(r["truth_vehicle_id"] == 0 and r["observer_id"] != 1 for r in ranked)
    from PIL import Image

    with Image.open(sheet) as im:  # 5 query crops above 3 results
        assert im.format == "PNG" and im.size == (6 + 5 * (128 + 6), 6 + 2 * (128 + 30 + 6))
    # the human summary lists the k tracks
    assert main(["reid", "query", str(embedded), "--track", str(trk), "--observer", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "mean embedding" in lines[0] and lines[1].split()[:3] == ["rank", "observer", "track"]
    assert len(lines) == 2 + min(10, out["tracks_searched"])


def test_image_query_of_a_stored_crop_ranks_its_track_first(embedded, tmp_path, capsys):
    with SightingsDB.open(embedded) as db:
        e = db.embeddings(_sha(db))
        i = int(np.flatnonzero(e.track_id >= 0)[len(e) // 2])
        (crop,) = db.crops(keys=[e.keys()[i]])
    img = tmp_path / "q.jpg"
    img.write_bytes(crop.jpeg)  # the very bytes in the database: the same vector
    assert main(["reid", "query", str(embedded), "--image", str(img), "--k", "4",
                 "--aggregate", "min", "--json"]) == 0
    out = _json(capsys)
    first = out["results"][0]
    assert (first["observer_id"], first["track_id"]) == (int(e.observer_id[i]),
                                                         int(e.track_id[i]))
    assert (first["best_frame"], first["best_idx"]) == (int(e.frame[i]), int(e.idx[i]))
    assert first["distance"] < 1e-5 and len(out["results"]) == 4
    # an existing sheet is refused without --overwrite, replaced whole with it
    sheet = tmp_path / "s.png"
    sheet.write_bytes(b"old")
    assert main(["reid", "query", str(embedded), "--image", str(img), "-o", str(sheet)]) == 2
    assert sheet.read_bytes() == b"old"
    assert main(["reid", "query", str(embedded), "--image", str(img), "-o", str(sheet),
                 "--overwrite", "--k", "2"]) == 0
    assert sheet.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_embed_and_query_a_run_in_postgres_as_in_its_file(run_db, embedded, pg_url, capsys,
                                                          tmp_path):
    """The run copied into PostgreSQL (`dashtraj sightings-copy`), embedded there, gives the
    file's vectors, and a track query the file's answer."""
    assert main(["sightings-copy", str(run_db), "-o", pg_url]) == 0
    capsys.readouterr()
    assert main(["reid", "embed", pg_url, "-q", "--json"]) == 0
    out = _json(capsys)
    assert "schema=" in out["db"] and out["added"] > 100
    with SightingsDB.open(embedded) as f, SightingsDB.open(pg_url) as p:
        a, b = f.embeddings(_sha(f)), p.embeddings(_sha(p))
    assert a.keys() == b.keys() and np.allclose(a.vectors, b.vectors, atol=1e-6)
    trk = int(a.track_id[np.flatnonzero(a.track_id >= 0)[0]])
    obs = int(a.observer_id[np.flatnonzero(a.track_id >= 0)[0]])
    answers = []
    for db in (str(embedded), pg_url):
        assert main(["reid", "query", db, "--track", str(trk), "--observer", str(obs), "--k",
                     "5", "--json"]) == 0
        answers.append(_json(capsys)["results"])
    assert answers[0] == answers[1] and len(answers[0]) == 5
