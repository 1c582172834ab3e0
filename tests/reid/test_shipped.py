"""The shipped ONNX ReID model on held-out vehicles seen by unseen cameras."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from dashtraj.reid.embed import ReidEmbedder, join_model_path, shipped_model_path
from dashtraj.render.look import preset

LOOK = None
"""Render look of the held-out set: None, the renderer's default (the shipped model was
trained on per-image randomized looks around it)."""


SIZES = {"shipped_model_path": (160, 160, 512), "join_model_path": (128, 128, 512)}
"""Input height, width and embedding size of each shipped model: the shipped model is one
160-px network (stage 12; stage 11 was an ensemble of a 128-px and a 160-px network, `dashtraj
reid ensemble`), the join model one 128-px network."""


@pytest.mark.parametrize("path", [shipped_model_path, join_model_path],
                         ids=["shipped", "join"])
def test_shipped_model_is_small_and_matches_its_card(path):
    p = path()
    assert p.is_file() and p.stat().st_size <= 10_000_000
    card = p.with_suffix(".md").read_text(encoding="utf-8")
    assert hashlib.sha256(p.read_bytes()).hexdigest() in card
    e = ReidEmbedder(p, threads=1)
    assert (e.height, e.width, e.dim) == SIZES[path.__name__]
    f = e.embed_array(np.zeros((2, e.height, e.width, 3), np.uint8))
    assert f.shape == (2, e.dim) and np.allclose(np.linalg.norm(f, axis=1), 1.0, atol=1e-5)


@pytest.fixture(scope="module")
def held_out(tmp_path_factory, gl_available):
    """10 test identities (ids 651-660, never trained on) x 40 ring cameras drawn with
    another seed than the training set's; (query, gallery, figures of the shipped model)."""
    from dashtraj.datasets.reid import ReidConfig, _Stage
    from dashtraj.reid.evaluate import evaluate_features, open_veri
    from dashtraj.world import catalog
    from dashtraj.world.towns import town_path

    root = tmp_path_factory.mktemp("held_out")
    cfg = ReidConfig(n_ids=700, n_cameras=40, seed=99)
    for s in ("train", "query", "test"):
        (root / f"image_{s}").mkdir()
    stage = _Stage(cfg, str(town_path("town10")), str(root))
    try:
        for iid in range(650, 660):
            ident = catalog.identities()[iid]
            if LOOK is not None:
                for cam in stage.cameras:
                    stage.renderer(stage.camera_pose(cam, ident.model)[1]).set_look(preset(LOOK))
            stage.identity_images(ident)
    finally:
        stage.release()
    q, g = open_veri(root)
    assert len(set(q.pids.tolist())) == 10 and not any((root / "image_train").iterdir())
    e = ReidEmbedder(threads=2)
    qf, gf = e.embed(q.paths), e.embed(g.paths)
    return q, g, qf, gf, evaluate_features(qf, gf, q, g)


def test_shipped_model_beats_chance(held_out):
    """Bar: mAP above the best of 20 random embeddings on the same queries and gallery (random mean
    0.115) and at least 0.5 (measured for the shipped model, stage 12, one 160-px network: mAP
    0.907, rank-1 0.925; stage 11, the ensemble of a 128-px and a 160-px network, 0.900 / 0.900;
    stage 10 0.887 / 0.900; stage 9 0.884 / 0.900, stage 8 0.878 / 0.900, stage 7 0.866 /
    0.925, stage 6 0.869 / 0.850, stage 5 0.844 / 0.850, stage 3 0.837 / 0.825, stage 2 0.800 /
    0.725, stage 1 0.771 / 0.725;
    the model before the catalog's trims 0.672 / 0.70 on these renders, 0.650 / 0.50 on the
    renders before them), rank-1 above the random mean. This catches a broken export,
    preprocessing or weights; it is below the paper's figures (see the next test)."""
    from dashtraj.reid.evaluate import evaluate_features

    q, g, qf, gf, r = held_out
    rng = np.random.default_rng(0)
    rand = [evaluate_features(rng.normal(size=qf.shape), rng.normal(size=gf.shape), q, g)
            for _ in range(20)]
    assert r["map"] > max(x["map"] for x in rand), r
    assert r["map"] >= 0.5, r
    assert r["rank1"] > np.mean([x["rank1"] for x in rand]), r


def test_shipped_model_ranks_the_right_identity_first(held_out):
    """Bar: rank-1 >= 80 % of the queries under the VeRi rule (the issue: 'most queries'). The
    shipped model (stage 12) ranks 37 of these 40 queries right (0.925; stage 11 36, as stages
    10, 9 and 8; stage 7: 37; stage 6: 34, as stage 5; stage 3: 33); stage 2 reached 0.725 and
    failed this bar, which was an expected failure until stage 3."""
    assert held_out[4]["rank1"] >= 0.8, held_out[4]


def test_join_model_ranks_the_right_identity_first_too(held_out):
    """The track-join model (stage 6, the shipped model of its time, trained on with shrunk images)
    on the same held-out queries: measured rank-1 0.825, mAP 0.835 (the shipped model, stage 12,
    0.925 / 0.907; stage 11 0.900 / 0.900; stage 10 0.900 / 0.887; stage 9 0.900 / 0.884; stage
    8 0.900 / 0.878; stage 7 0.925 / 0.866; stage 6 0.850 / 0.869); bar rank-1 >= 80 %, as the
    shipped model's, and not an export of the shipped model itself (its embeddings of the same
    crops differ)."""
    from dashtraj.reid.evaluate import evaluate_features

    q, g, qf, _, _ = held_out
    e = ReidEmbedder(join_model_path(), threads=2)
    jf, jg = e.embed(q.paths), e.embed(g.paths)
    r = evaluate_features(jf, jg, q, g)
    assert r["rank1"] >= 0.8 and r["map"] >= 0.5, r
    # another model's embeddings (the shipped ensemble's are longer; were they not, they
    # would differ)
    assert jf.shape[1] != qf.shape[1] or np.median(np.sum(jf * qf, axis=1)) < 0.99


def test_flip_embedding_is_the_same_for_a_crop_and_its_mirror_image():
    """Test-time flip (`ReidEmbedder(flip=True)`) sums the embeddings of a crop and of its
    mirror image: a crop and its mirror get one vector, unlike the plain embedding; the
    sightings database refuses such vectors (its rows are keyed by the model file)."""
    from dashtraj.reid.database import embed_database

    rng = np.random.default_rng(0)
    flip = ReidEmbedder(threads=1, flip=True)
    plain = ReidEmbedder(threads=1)
    imgs = rng.integers(0, 255, (3, plain.height, plain.width, 3), np.uint8)
    mirror = np.ascontiguousarray(imgs[:, :, ::-1])
    f, fm = flip.embed_array(imgs), flip.embed_array(mirror)
    assert np.allclose(f, fm, atol=1e-5)
    p, pm = plain.embed_array(imgs), plain.embed_array(mirror)
    assert np.abs(p - pm).max() > 1e-3
    raw = plain.embed_array(imgs, normalize=False) + plain.embed_array(mirror, normalize=False)
    assert np.allclose(f, raw / np.linalg.norm(raw, axis=1, keepdims=True), atol=1e-5)
    with pytest.raises(ValueError, match="flip"):
        embed_database(None, flip)


def test_embed_boxes_crops_each_box_as_a_sighting_and_skips_small_ones():
    """`ReidEmbedder.embed_boxes`: a box's row is the embedding of its crop with 10 %
    margin (`crop_vehicle`, as `perceive` crops a sighting); a box under the height floor
    gets a NaN row; no boxes, no rows."""
    from dashtraj.datasets.frames import crop_vehicle

    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (90, 160, 3), dtype=np.uint8)
    rgb[20:60, 30:90] = (200, 30, 30)
    boxes = np.array([[30.0, 20.0, 90.0, 60.0], [100.0, 10.0, 110.0, 18.0]])  # 40 and 8 px
    e = ReidEmbedder(threads=1)
    got = e.embed_boxes(rgb, boxes, min_height_px=10.0)
    assert got.shape == (2, e.dim) and got.dtype == np.float32
    assert np.isnan(got[1]).all() and np.isfinite(got[0]).all()
    np.testing.assert_allclose(got[0], e.embed([crop_vehicle(rgb, boxes[0], 0.1)])[0],
                               atol=1e-6)
    assert abs(float(np.linalg.norm(got[0])) - 1.0) < 1e-5
    assert e.embed_boxes(rgb, np.zeros((0, 4))).shape == (0, e.dim)
