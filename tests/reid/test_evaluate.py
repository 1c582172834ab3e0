"""VeRi-protocol evaluation against an independent brute-force reference."""

from __future__ import annotations

import numpy as np
import pytest

from dashtraj.cli import main
from dashtraj.reid.evaluate import distance_matrix, evaluate_rank, open_veri, read_split


def reference(dist, q_pids, g_pids, q_cams, g_cams):
    """Query by query, written from the protocol's definition with plain Python lists."""
    r1, r5, aps, inps, n = 0, 0, [], [], 0
    for i in range(len(q_pids)):
        ranked = sorted(range(len(g_pids)), key=lambda j: (dist[i][j], j))
        kept = [j for j in ranked if not (g_pids[j] == q_pids[i] and g_cams[j] == q_cams[i])]
        rel = [g_pids[j] == q_pids[i] for j in kept]
        if not any(rel):
            continue
        n += 1
        r1 += rel[0]
        r5 += any(rel[:5])
        hits, precisions = 0, []
        for rank, good in enumerate(rel, start=1):
            if good:
                hits += 1
                precisions.append(hits / rank)
        aps.append(sum(precisions) / len(precisions))
        last = max(rank for rank, good in enumerate(rel, start=1) if good)
        inps.append(sum(rel) / last)
    return {"rank1": r1 / n, "rank5": r5 / n, "map": sum(aps) / n, "minp": sum(inps) / n,
            "queries": n}


def test_hand_worked_example():
    # gallery by distance: same id+cam (excluded), other id, same id, other id, same id
    d = np.array([[0.1, 0.2, 0.3, 0.4, 0.5]])
    r = evaluate_rank(d, [7], [7, 3, 7, 4, 7], [1], [1, 2, 2, 3, 5])
    assert r["rank1"] == 0.0 and r["rank5"] == 1.0
    assert r["map"] == pytest.approx((1 / 2 + 2 / 4) / 2)
    assert r["minp"] == pytest.approx(2 / 4)
    # without VeRi's exclusion the first image would have been a hit
    r2 = evaluate_rank(d, [7], [7, 3, 7, 4, 7], [1], [9, 2, 2, 3, 5])
    assert r2["rank1"] == 1.0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_matches_brute_force_reference(seed):
    rng = np.random.default_rng(seed)
    nq, ng, ids, cams = 40, 300, 12, 6
    q_pids, g_pids = rng.integers(0, ids, nq), rng.integers(0, ids, ng)
    q_cams, g_cams = rng.integers(0, cams, nq), rng.integers(0, cams, ng)
    # features clustered by identity so that rank-1 and mAP are neither 0 nor 1
    centres = rng.normal(size=(ids, 16))
    qf = centres[q_pids] + rng.normal(scale=1.2, size=(nq, 16))
    gf = centres[g_pids] + rng.normal(scale=1.2, size=(ng, 16))
    dist = distance_matrix(qf, gf)
    got = evaluate_rank(dist, q_pids, g_pids, q_cams, g_cams)
    ref = reference(dist.tolist(), q_pids.tolist(), g_pids.tolist(), q_cams.tolist(),
                    g_cams.tolist())
    assert 0.2 < ref["rank1"] < 1.0 and 0.1 < ref["map"] < 0.9
    for k in ("rank1", "rank5", "map", "minp", "queries"):
        assert got[k] == pytest.approx(ref[k], abs=1e-12), k


def test_query_without_cross_camera_match_is_skipped():
    d = np.array([[0.1, 0.2], [0.3, 0.1]])
    r = evaluate_rank(d, [1, 2], [1, 2], [1, 1], [1, 2])  # query 0's only match: same camera
    assert r["queries"] == 1 and r["skipped"] == 1 and r["rank1"] == 1.0


def _jpeg(path):
    from PIL import Image

    Image.new("RGB", (8, 8), (200, 10, 10)).save(path)


def test_open_veri_reads_ids_and_cameras(tmp_path):
    for sub, names in (("image_query", ["0002_c002_00030600_0.jpg"]),
                       ("image_test", ["0002_c003_00084280_0.jpg", "0011_c017_00000000_0.jpg"])):
        (tmp_path / sub).mkdir()
        for n in names:
            _jpeg(tmp_path / sub / n)
    q, g = open_veri(tmp_path)
    assert q.pids.tolist() == [2] and q.camids.tolist() == [2]
    assert g.pids.tolist() == [2, 11] and g.camids.tolist() == [3, 17]


def test_cli_refuses_a_folder_not_in_veri_layout(tmp_path, capsys):
    (tmp_path / "images").mkdir()
    assert main(["reid", "eval", "--data", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert "not a VeRi-776 layout folder" in err and "image_query/" in err


def test_cli_refuses_a_badly_named_image(tmp_path, capsys):
    for sub in ("image_query", "image_test"):
        (tmp_path / sub).mkdir()
    _jpeg(tmp_path / "image_query" / "car_front.jpg")
    assert main(["reid", "eval", "--data", str(tmp_path)]) == 2
    assert "car_front.jpg: not a VeRi image name" in capsys.readouterr().err


def test_read_split_of_missing_folder(tmp_path):
    from dashtraj.reid.evaluate import VeriLayoutError

    with pytest.raises(VeriLayoutError, match="no such folder"):
        read_split(tmp_path / "image_train")


def test_cli_flip_reports_it_and_scores_like_the_library(tmp_path, capsys):
    """`reid eval --flip` embeds with the mirror images too and says so; its figures are
    the library's on the same embeddings."""
    import json

    from PIL import Image

    from dashtraj.reid.embed import ReidEmbedder
    from dashtraj.reid.evaluate import evaluate_features

    rng = np.random.default_rng(3)
    for sub, names in (("image_query", ["0001_c001_a.jpg", "0002_c001_b.jpg"]),
                       ("image_test", ["0001_c002_c.jpg", "0002_c002_d.jpg",
                                       "0003_c003_e.jpg"])):
        (tmp_path / sub).mkdir()
        for n in names:
            Image.fromarray(rng.integers(0, 255, (40, 60, 3), np.uint8)).save(tmp_path / sub / n)
    assert main(["reid", "eval", "--data", str(tmp_path), "--flip", "--json",
                 "--threads", "1"]) == 0
    out = json.loads(capsys.readouterr().out)
    q, g = open_veri(tmp_path)
    e = ReidEmbedder(threads=1, flip=True)
    ref = evaluate_features(e.embed(q.paths), e.embed(g.paths), q, g)
    assert out["flip"] is True and out["queries"] == 2
    assert out["map"] == pytest.approx(ref["map"]) and out["rank1"] == ref["rank1"]


def test_cli_rerank_reports_both_and_scores_like_the_library(tmp_path, capsys):
    """`reid eval --rerank` scores the re-ranked distances, names its parameters and keeps
    the figures without re-ranking beside them."""
    import json

    from PIL import Image

    from dashtraj.reid.embed import ReidEmbedder
    from dashtraj.reid.evaluate import evaluate_features

    rng = np.random.default_rng(4)
    for sub, names in (("image_query", ["0001_c001_a.jpg", "0002_c001_b.jpg"]),
                       ("image_test", ["0001_c002_c.jpg", "0002_c002_d.jpg", "0001_c003_f.jpg",
                                       "0003_c003_e.jpg"])):
        (tmp_path / sub).mkdir()
        for n in names:
            Image.fromarray(rng.integers(0, 255, (40, 60, 3), np.uint8)).save(tmp_path / sub / n)
    assert main(["reid", "eval", "--data", str(tmp_path), "--rerank", "--rerank-k1", "2",
                 "--rerank-k2", "1", "--json", "--threads", "1"]) == 0
    out = json.loads(capsys.readouterr().out)
    q, g = open_veri(tmp_path)
    e = ReidEmbedder(threads=1)
    qf, gf = e.embed(q.paths), e.embed(g.paths)
    rr = evaluate_features(qf, gf, q, g, rerank={"k1": 2, "k2": 1, "lambda_value": 0.3})
    plain = evaluate_features(qf, gf, q, g)
    assert out["rerank"] == {"k1": 2, "k2": 1, "lambda_value": 0.3}
    assert out["map"] == pytest.approx(rr["map"]) and out["rank1"] == rr["rank1"]
    assert out["without_rerank"]["map"] == pytest.approx(plain["map"])


@pytest.mark.parametrize("seed", [0, 1])
def test_rank1_errors_are_the_reference_misses(seed):
    """`rank1_errors` lists exactly the queries the brute-force reference ranks wrong, with
    the reference's nearest image and first true rank, under VeRi's exclusion rule."""
    from pathlib import Path

    from dashtraj.reid.evaluate import VeriSplit, rank1_errors

    rng = np.random.default_rng(seed)
    nq, ng, ids, cams = 30, 200, 10, 5
    q_pids, g_pids = rng.integers(0, ids, nq), rng.integers(0, ids, ng)
    q_cams, g_cams = rng.integers(0, cams, nq), rng.integers(0, cams, ng)
    centres = rng.normal(size=(ids, 16))
    dist = distance_matrix(centres[q_pids] + rng.normal(scale=1.2, size=(nq, 16)),
                           centres[g_pids] + rng.normal(scale=1.2, size=(ng, 16)))
    q = VeriSplit(tuple(Path(f"q{i}.jpg") for i in range(nq)), q_pids, q_cams)
    g = VeriSplit(tuple(Path(f"g{j}.jpg") for j in range(ng)), g_pids, g_cams)
    want = []
    for i in range(nq):
        ranked = sorted(range(ng), key=lambda j: (dist[i][j], j))
        kept = [j for j in ranked if not (g_pids[j] == q_pids[i] and g_cams[j] == q_cams[i])]
        rel = [g_pids[j] == q_pids[i] for j in kept]
        if any(rel) and not rel[0]:
            want.append((f"q{i}.jpg", f"g{kept[0]}.jpg", rel.index(True) + 1))
    got = rank1_errors(dist, q, g)
    assert [(e["query"], e["nearest"], e["true_rank"]) for e in got] == want
    ref = reference(dist.tolist(), q_pids.tolist(), g_pids.tolist(), q_cams.tolist(),
                    g_cams.tolist())
    assert 0 < len(got) == round((1 - ref["rank1"]) * ref["queries"])
    assert all(e["nearest_id"] != e["query_id"] and e["distance"] <= e["true_distance"]
               for e in got)


def test_cli_errors_lists_the_misses_with_catalog_keys(tmp_path, capsys):
    """`reid eval --errors`: one entry per rank-1 miss of the library's figures, both
    identities' keys from reid.json, the confusions counted; a broken reid.json is exit 2."""
    import json

    from PIL import Image

    rng = np.random.default_rng(5)
    for sub, names in (("image_query", [f"000{i}_c001_q.jpg" for i in (1, 2, 3)]),
                       ("image_test", [f"000{i}_c00{c}_g.jpg" for i in (1, 2, 3)
                                       for c in (2, 3)])):
        (tmp_path / sub).mkdir()
        for n in names:
            Image.fromarray(rng.integers(0, 255, (40, 60, 3), np.uint8)).save(tmp_path / sub / n)
    keys = {1: "vehicle.a/red", 2: "vehicle.b/red", 3: "vehicle.c/blue"}
    (tmp_path / "reid.json").write_text(json.dumps(
        {"ids": [{"id": i, "key": k} for i, k in keys.items()]}))
    assert main(["reid", "eval", "--data", str(tmp_path), "--errors", "--json",
                 "--threads", "1"]) == 0
    out = json.loads(capsys.readouterr().out)
    errs = out["rank1_errors"]
    assert errs  # noise images: any model misses some (the shipped one 2 of 3)
    assert len(errs) == round((1 - out["rank1"]) * out["queries"])
    for e in errs:
        assert e["query_key"] == keys[e["query_id"]] and e["nearest_key"] == keys[e["nearest_id"]]
    assert sum(c["errors"] for c in out["confusions"]) == len(errs)
    (tmp_path / "reid.json").write_text("{not json")
    assert main(["reid", "eval", "--data", str(tmp_path), "--errors", "--threads", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "reid.json" in err
