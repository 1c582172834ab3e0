"""ReID ensembles (`dashtraj reid ensemble`, `dashtraj.train.reid_ensemble`; onnx): the joined
model's embedding against its members' run one by one on onnxruntime."""

from __future__ import annotations

import json

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")


def _member(path, size: int, seed: int, dim: int = 16, mean: str = "[0.485, 0.456, 0.406]",
            reduce_mean: bool = False):
    """A small ReID-shaped ONNX model as `reid export` writes one: images (batch, 3, size,
    size) → Conv 3→64 (3x3) → Relu → global pooling → Gemm → ``dim``; metadata with the
    input size and normalisation; weights from ``seed``. ``reduce_mean``: pool with opset
    17's ReduceMean (its axes an attribute, an input from opset 18 on)."""
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(seed)
    w = rng.normal(0, 0.3, (64, 3, 3, 3)).astype(np.float32)
    b = rng.normal(0, 0.1, 64).astype(np.float32)
    fc = rng.normal(0, 0.3, (dim, 64)).astype(np.float32)
    fb = rng.normal(0, 0.1, dim).astype(np.float32)
    nodes = [helper.make_node("Conv", ["images", "w", "b"], ["c"], pads=[1, 1, 1, 1]),
             helper.make_node("Relu", ["c"], ["r"]),
             helper.make_node("ReduceMean", ["r"], ["p"], axes=[2, 3], keepdims=1)
             if reduce_mean else helper.make_node("GlobalAveragePool", ["r"], ["p"]),
             helper.make_node("Flatten", ["p"], ["f"]),
             helper.make_node("Gemm", ["f", "fc", "fb"], ["embedding"], transB=1)]
    g = helper.make_graph(
        nodes, "member",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, ["batch", 3, size, size])],
        [helper.make_tensor_value_info("embedding", TensorProto.FLOAT, ["batch", dim])],
        initializer=[numpy_helper.from_array(a, n)
                     for a, n in ((w, "w"), (b, "b"), (fc, "fc"), (fb, "fb"))])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    for k, v in {"model": "tiny", "input_height": str(size), "input_width": str(size),
                 "mean": mean, "std": "[0.229, 0.224, 0.225]", "feature_dim": str(dim)}.items():
        p = m.metadata_props.add()
        p.key, p.value = k, v
    onnx.save(m, str(path))
    return path


def _run(path, x: np.ndarray) -> np.ndarray:
    s = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return s.run(None, {s.get_inputs()[0].name: x})[0]


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _pil_resize(x: np.ndarray, size: int) -> np.ndarray:
    """(N, 3, H, W) float32 resized per channel by Pillow's bilinear filter (antialiased when
    it shrinks), as the embedder resizes each crop: the reference for the graph's Resize."""
    from PIL import Image

    return np.stack([np.stack([np.asarray(Image.fromarray(c, mode="F").resize(
        (size, size), Image.Resampling.BILINEAR)) for c in img]) for img in x]).astype(np.float32)


def test_ensemble_is_the_weighted_concatenation_of_its_members(tmp_path):
    from dashtraj.train.reid_ensemble import build_ensemble

    a = _member(tmp_path / "a.onnx", 16, seed=0)
    b = _member(tmp_path / "b.onnx", 20, seed=1)
    out = tmp_path / "ens.onnx"
    meta = build_ensemble([a, b], out, weights=[1.0, 3.0])
    assert (meta["input_height"], meta["input_width"], meta["feature_dim"]) == ("20", "20", "32")
    members = json.loads(meta["ensemble"])
    assert [(x["input_height"], x["weight"]) for x in members] == [(16, 1.0), (20, 3.0)]
    x = np.random.default_rng(2).normal(0, 1, (5, 3, 20, 20)).astype(np.float32)
    e = _run(out, x)
    assert e.shape == (5, 32)
    np.testing.assert_allclose(np.linalg.norm(e, axis=1), 1.0, atol=1e-5)
    # the 20-px member reads the input as it is; the 16-px one a resized copy (Pillow's
    # filter here; weights stored as float16: 1e-3)
    ea = np.sqrt(0.25) * _unit(_run(a, _pil_resize(x, 16)))
    eb = np.sqrt(0.75) * _unit(_run(b, x))
    np.testing.assert_allclose(e[:, 16:], eb, atol=2e-3)
    np.testing.assert_allclose(e[:, :16], ea, atol=5e-3)
    # the squared distance is the weighted mean of the members'
    d = ((e[0] - e[1:]) ** 2).sum(1)
    ua, ub = _unit(_run(a, _pil_resize(x, 16))), _unit(_run(b, x))
    da, db = ((ua[0] - ua[1:]) ** 2).sum(1), ((ub[0] - ub[1:]) ** 2).sum(1)
    np.testing.assert_allclose(d, 0.25 * da + 0.75 * db, atol=1e-2)
    # a constant image stays constant under any resize: the 16-px half is exact there
    c = np.full((1, 3, 20, 20), 0.7, np.float32)
    np.testing.assert_allclose(_run(out, c)[:, :16],
                               0.5 * _unit(_run(a, np.full((1, 3, 16, 16), 0.7, np.float32))),
                               atol=2e-3)


def test_a_member_of_an_older_opset_is_converted(tmp_path):
    """A member whose operators opset 18 changed (here ReduceMean) is converted before it
    joins; the ensemble still embeds as the member does, and the member comes back out."""
    from dashtraj.train.reid_ensemble import build_ensemble, extract_member

    a = _member(tmp_path / "a.onnx", 16, seed=0, reduce_mean=True)
    b = _member(tmp_path / "b.onnx", 16, seed=1)
    ens = tmp_path / "ens.onnx"
    build_ensemble([a, b], ens)
    x = np.random.default_rng(5).normal(0, 1, (3, 3, 16, 16)).astype(np.float32)
    np.testing.assert_allclose(_run(ens, x)[:, :16], np.sqrt(0.5) * _unit(_run(a, x)),
                               atol=2e-3)
    extract_member(ens, 1, tmp_path / "m1.onnx")
    np.testing.assert_allclose(_unit(_run(tmp_path / "m1.onnx", x)), _unit(_run(a, x)),
                               atol=2e-3)


def test_int8_weights_halve_the_file_and_keep_the_embedding(tmp_path):
    from dashtraj.train.reid_ensemble import build_ensemble, quantize_int8

    w = np.random.default_rng(3).normal(0, 1, (64, 3, 3, 3)).astype(np.float32)
    w[5] = 0.0
    q, s = quantize_int8(w)
    assert q.dtype == np.int8 and s.shape == (64,) and s[5] == 1.0
    err = np.abs(q * s[:, None, None, None] - w)
    assert (err <= s[:, None, None, None] / 2 + 1e-7).all()
    a = _member(tmp_path / "a.onnx", 16, seed=0, dim=64)
    b = _member(tmp_path / "b.onnx", 16, seed=1, dim=64)
    f16, i8 = tmp_path / "f16.onnx", tmp_path / "i8.onnx"
    build_ensemble([a, b], f16)
    meta = build_ensemble([a, b], i8, int8=True)
    assert meta["weights_dtype"] == "int8 per output channel"
    assert i8.stat().st_size < 0.7 * f16.stat().st_size
    x = np.random.default_rng(4).normal(0, 1, (8, 3, 16, 16)).astype(np.float32)
    cos = (_run(f16, x) * _run(i8, x)).sum(1)
    assert cos.min() > 0.999


def test_embedder_reads_the_ensemble(tmp_path):
    from dashtraj.reid.embed import ReidEmbedder
    from dashtraj.train.reid_ensemble import build_ensemble

    out = tmp_path / "ens.onnx"
    build_ensemble([_member(tmp_path / "a.onnx", 16, 0), _member(tmp_path / "b.onnx", 20, 1)],
                   out, int8=True)
    e = ReidEmbedder(out, threads=1)
    assert (e.height, e.width, e.dim) == (20, 20, 32)
    crops = [np.random.default_rng(i).integers(0, 255, (30 + i, 12 + i, 3), np.uint8)
             for i in range(3)]
    v = e.embed(crops)
    assert v.shape == (3, 32) and np.allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-5)
    assert e.embed([]).shape == (0, 32)
    boxes = np.array([[0, 0, 10, 20], [5, 5, 25, 30]], float)
    rgb = np.random.default_rng(9).integers(0, 255, (40, 40, 3), np.uint8)
    got = e.embed_boxes(rgb, boxes, min_height_px=22)
    assert got.shape == (2, 32) and np.isnan(got[0]).all() and np.isfinite(got[1]).all()


def test_ensemble_refuses_what_does_not_fit(tmp_path):
    from dashtraj.train.reid_ensemble import EnsembleError, build_ensemble

    a = _member(tmp_path / "a.onnx", 16, 0)
    b = _member(tmp_path / "b.onnx", 16, 1, mean="[0.5, 0.5, 0.5]")
    ens = tmp_path / "ens.onnx"
    build_ensemble([a, _member(tmp_path / "c.onnx", 16, 2)], ens)
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not onnx")
    bare = tmp_path / "bare.onnx"
    m = onnx.load(str(a))
    del m.metadata_props[:]
    onnx.save(m, str(bare))
    cases = [([a], "two or more"), ([a, b], "normalise their input differently"),
             ([a, ens], "already an ensemble"), ([a, junk], "not an ONNX model"),
             ([a, bare], "not a model of 'dashtraj reid export'"),
             ([a, tmp_path / "none.onnx"], "no such file")]
    for paths, why in cases:
        with pytest.raises(EnsembleError, match=why):
            build_ensemble(paths, tmp_path / "out.onnx")
    with pytest.raises(EnsembleError, match="positive"):
        build_ensemble([a, a], tmp_path / "out.onnx", weights=[1.0, 0.0])


def test_ensemble_command(tmp_path, capsys):
    from dashtraj.cli import main

    a = _member(tmp_path / "a.onnx", 16, 0)
    b = _member(tmp_path / "b.onnx", 20, 1)
    out = tmp_path / "ens.onnx"
    assert main(["reid", "ensemble", str(a), str(b), "-o", str(out), "--int8-weights",
                 "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["feature_dim"] == "32" and [m["file"] for m in info["ensemble"]] == [
        "a.onnx", "b.onnx"]
    first = out.read_bytes()
    # the same members give the same bytes
    assert main(["reid", "ensemble", str(a), str(b), "-o", str(out), "--int8-weights",
                 "--overwrite"]) == 0
    assert out.read_bytes() == first
    capsys.readouterr()
    # bad input (even with --overwrite) and an existing output without it: exit 2, one
    # line, the existing output kept, nothing else written
    for args, why in [([str(a), str(b), "--weights", "1", "--overwrite"],
                       "--weights: 1 weights for 2"),
                      ([str(a), str(b), "--weights", "1,x", "--overwrite"], "--weights"),
                      ([str(a), str(out), "--overwrite"], "already an ensemble"),
                      ([str(a), str(b)], "--overwrite")]:
        assert main(["reid", "ensemble", *args, "-o", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and why in err and "Traceback" not in err, err
        assert out.read_bytes() == first
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.onnx", "b.onnx", "ens.onnx"]


@pytest.mark.parametrize("int8", [False, True], ids=["float16", "int8"])
def test_a_member_comes_back_out_whole(tmp_path, int8):
    """`extract_member`: each member of an ensemble written back alone embeds as the model it
    was built from (to the storage's rounding), at its own input size, with its metadata."""
    from dashtraj.reid.embed import ReidEmbedder
    from dashtraj.train.reid_ensemble import EnsembleError, build_ensemble, extract_member

    a = _member(tmp_path / "a.onnx", 16, seed=0)
    b = _member(tmp_path / "b.onnx", 20, seed=1, dim=8)
    ens = tmp_path / "ens.onnx"
    build_ensemble([a, b], ens, int8=int8)
    for i, (src, size, dim) in enumerate([(a, 16, 16), (b, 20, 8)], start=1):
        out = tmp_path / f"m{i}.onnx"
        meta = extract_member(ens, i, out)
        assert (meta["input_height"], meta["feature_dim"]) == (str(size), str(dim))
        x = np.random.default_rng(i).normal(0, 1, (4, 3, size, size)).astype(np.float32)
        got, want = _unit(_run(out, x)), _unit(_run(src, x))
        assert got.shape == (4, dim)
        assert (got * want).sum(1).min() > (0.999 if int8 else 0.99999)
        e = ReidEmbedder(out, threads=1)
        assert (e.height, e.dim) == (size, dim) and "ensemble" not in e.metadata
    with pytest.raises(EnsembleError, match="has members 1 to 2"):
        extract_member(ens, 3, tmp_path / "x.onnx")
    with pytest.raises(EnsembleError, match="not an ensemble"):
        extract_member(a, 1, tmp_path / "x.onnx")


def test_member_command(tmp_path, capsys):
    from dashtraj.cli import main
    from dashtraj.train.reid_ensemble import build_ensemble

    ens = tmp_path / "ens.onnx"
    build_ensemble([_member(tmp_path / "a.onnx", 16, 0), _member(tmp_path / "b.onnx", 20, 1)],
                   ens, int8=True)
    out = tmp_path / "m2.onnx"
    assert main(["reid", "member", str(ens), "2", "-o", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["input_height"] == "20"
    first = out.read_bytes()
    for args, why in [([str(ens), "3", "-o", str(out), "--overwrite"], "has members 1 to 2"),
                      ([str(ens), "0", "-o", str(out), "--overwrite"], "argument N"),
                      ([str(ens), "1", "-o", str(out)], "--overwrite")]:
        assert main(["reid", "member", *args]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and why in err and "Traceback" not in err, err
        assert out.read_bytes() == first


def test_training_refuses_an_ensemble_as_init(tmp_path):
    pytest.importorskip("torch")  # dashtraj.reid.train's TrainError
    from dashtraj.reid.train import TrainError
    from dashtraj.train.reid_ensemble import build_ensemble
    from dashtraj.train.reid_onnx import check_onnx

    out = tmp_path / "ens.onnx"
    build_ensemble([_member(tmp_path / "a.onnx", 16, 0), _member(tmp_path / "b.onnx", 16, 1)],
                   out)
    with pytest.raises(TrainError, match=r"is an ensemble.*reid member ens\.onnx N"):
        check_onnx(out, "efficientnet_lite0", 16, 16)
