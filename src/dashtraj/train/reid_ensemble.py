"""Several exported ReID models joined into one ONNX file (`dashtraj reid ensemble`; onnx,
no torch).

Models trained at different input sizes see a vehicle differently (a 160-px model reads
more of a small crop's shape, a 128-px one keeps what its longer training taught), and their
errors differ more than those of cycles trained at one size, whose weights are averaged
instead (`dashtraj reid average`). The ensemble runs every member on one input and joins
their embeddings:

1. The input is the largest member's size; a smaller member reads it through a ``Resize``
   (linear, antialiased: what Pillow's bilinear resize of the crop itself does).
2. Each member's embedding is L2-normalised and scaled by √(wᵢ / Σw); the scaled vectors
   are concatenated. The result is unit length, and the squared L2 distance of two
   ensemble embeddings is the weighted mean of the members' squared distances, on the
   scale a threshold for one member is.
3. The members' weights are stored as float16 (as `reid export --fp16-weights` does) or,
   with ``int8``, as int8 with one scale per output channel (symmetric) and a ``Cast`` and
   ``Mul`` in front of each, which onnxruntime folds into float32 constants when it loads
   the file: inference stays float32, the file is half the float16 one.

The embedding grows to the sum of the members' sizes (1,024 for two 512-d members);
`ReidEmbedder` reads it from the model, the sightings database stores each vector's size.

Example:
    >>> build_ensemble(["a128.onnx", "b160.onnx"], "ens.onnx", int8=True)  # doctest: +SKIP
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from dashtraj.errors import DashtrajError

OPSET = 18
"""The ensemble's opset (Resize's ``antialias`` and ``axes`` need 18)."""

CHANGED_BY_18 = frozenset({
    "ReduceL1", "ReduceL2", "ReduceLogSum", "ReduceLogSumExp", "ReduceMax", "ReduceMean",
    "ReduceMin", "ReduceProd", "ReduceSumSquare", "Resize", "Pad", "Split", "ScatterElements",
    "ScatterND", "LpPool", "Col2Im", "CenterCropPad", "GroupNormalization",
    "OptionalHasElement", "OptionalGetElement", "BitwiseAnd", "BitwiseOr", "BitwiseXor",
    "BitwiseNot"})
"""Operators that opset 18 defines anew (new versions or new operators): a member of an older
opset that uses one is converted (`onnx.version_converter`) before it joins the ensemble;
the others keep their nodes as they are."""


class EnsembleError(DashtrajError):
    """A member is not an exported dashtraj ReID model, or the members do not fit together."""


def _load(path: Path):
    """(onnx model, metadata dict) of an ONNX file; EnsembleError naming it otherwise."""
    import onnx

    try:
        m = onnx.load(str(path))
    except FileNotFoundError:
        raise EnsembleError(f"{path}: no such file") from None
    except Exception as e:  # onnx raises protobuf's DecodeError and its own types
        raise EnsembleError(f"{path}: not an ONNX model ({type(e).__name__})") from None
    return m, {p.key: p.value for p in m.metadata_props}


def _save(model, meta: dict[str, str], output) -> None:
    """Write ``model`` to ``output`` with ``meta`` as its metadata."""
    import onnx

    for k, v in meta.items():
        p = model.metadata_props.add()
        p.key, p.value = k, v
    onnx.save(model, str(output))


def _member(path: Path):
    """(onnx model, metadata dict, (height, width), embedding size) of one exported model."""
    m, meta = _load(path)
    if "ensemble" in meta:
        raise EnsembleError(f"{path}: already an ensemble; give its members instead")
    if "model" not in meta or "input_height" not in meta:
        raise EnsembleError(f"{path}: not a model of 'dashtraj reid export' (no 'model' and "
                            "'input_height' metadata)")
    if len(m.graph.input) != 1 or len(m.graph.output) != 1:
        raise EnsembleError(f"{path}: a ReID model has one input and one output, this one "
                            f"{len(m.graph.input)} and {len(m.graph.output)}")
    out = m.graph.output[0].type.tensor_type.shape.dim
    if len(out) != 2 or not out[1].dim_value:
        raise EnsembleError(f"{path}: the output is not (batch, D) with a fixed D")
    size = (int(meta["input_height"]), int(meta["input_width"]))
    return m, meta, size, int(out[1].dim_value)


def _opset(m) -> int:
    """The default-domain opset a model imports."""
    return next((o.version for o in m.opset_import if o.domain in ("", "ai.onnx")), OPSET)


def _weights_as_float32(g) -> None:
    """Every float16 initializer that a ``Cast`` to float32 reads (`reid export
    --fp16-weights`) replaced by its float32 values under the Cast's output name; the Casts
    dropped. Other initializers stay."""
    from onnx import TensorProto, numpy_helper

    inits = {i.name: i for i in g.initializer}
    keep = []
    for n in g.node:
        src = inits.get(n.input[0]) if n.op_type == "Cast" and n.input else None
        if src is not None and src.data_type == TensorProto.FLOAT16:
            arr = numpy_helper.to_array(src).astype(np.float32)
            g.initializer.remove(src)
            del inits[src.name]
            g.initializer.append(numpy_helper.from_array(arr, n.output[0]))
            continue
        keep.append(n)
    del g.node[:]
    g.node.extend(keep)


def quantize_int8(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric per-output-channel (axis 0) int8: (q, scale) with w ≈ q × scale per row;
    a channel of zeros gets scale 1."""
    flat = np.abs(w.reshape(len(w), -1)).max(1) if w.ndim > 1 else np.abs(w)
    scale = np.where(flat > 0, flat / 127.0, 1.0).astype(np.float32)
    shape = (-1,) + (1,) * (w.ndim - 1)
    q = np.clip(np.rint(w / scale.reshape(shape)), -127, 127).astype(np.int8)
    return q, scale


def _store_int8(g, min_elements: int = 1024) -> int:
    """Large float32 initializers of rank ≥ 2 stored as int8 per output channel, each
    followed by a ``Cast`` to float32 and a ``Mul`` by its scales under its own name (constant
    subgraphs that onnxruntime folds when it loads the file; a ``DequantizeLinear`` it would
    keep and run on every call). Returns how many."""
    from onnx import TensorProto, helper, numpy_helper

    nodes, n = [], 0
    for init in list(g.initializer):
        if init.data_type != TensorProto.FLOAT or len(init.dims) < 2:
            continue
        arr = numpy_helper.to_array(init)
        if arr.size < min_elements:
            continue
        q, scale = quantize_int8(arr)
        name = init.name
        g.initializer.remove(init)
        g.initializer.extend([
            numpy_helper.from_array(q, name + "__int8"),
            numpy_helper.from_array(scale.reshape((-1,) + (1,) * (q.ndim - 1)),
                                    name + "__scale")])
        nodes.extend([
            helper.make_node("Cast", [name + "__int8"], [name + "__float"],
                             to=TensorProto.FLOAT, name=name + "__cast"),
            helper.make_node("Mul", [name + "__float", name + "__scale"], [name],
                             name=name + "__dequantize")])
        n += 1
    rest = list(g.node)
    del g.node[:]
    g.node.extend(nodes + rest)
    return n


def build_ensemble(paths, output, weights=None, int8: bool = False) -> dict:
    """Join exported ReID models (``paths``) into one ONNX file at ``output``.

    Args:
        paths: two or more `dashtraj reid export` files with the same input normalisation.
        output: the ensemble's path (written directly; callers wrap it in
            `dashtraj.outputs.atomic_output`).
        weights: one positive weight per member (default equal).
        int8: store the weights as int8 per output channel instead of float16.

    Returns:
        The metadata written into the file (``input_height``, ``feature_dim``, ``ensemble``:
        the members as JSON…).

    Raises:
        EnsembleError: fewer than two members, a member that is not an exported ReID model
            or an ensemble already, members with different mean/std or input sizes that do
            not nest, a member of a newer opset, bad weights.
    """
    import onnx
    from onnx import TensorProto, compose, helper, numpy_helper

    paths = [Path(p) for p in paths]
    if len(paths) < 2:
        raise EnsembleError("an ensemble needs two or more models")
    weights = [1.0] * len(paths) if weights is None else [float(w) for w in weights]
    if len(weights) != len(paths):
        raise EnsembleError(f"{len(weights)} weights for {len(paths)} models")
    if not all(np.isfinite(w) and w > 0 for w in weights):
        raise EnsembleError(f"weights must be positive numbers, got {weights}")
    members = [_member(p) for p in paths]
    norm = {(mt.get("mean"), mt.get("std")) for _, mt, _, _ in members}
    if len(norm) != 1:
        raise EnsembleError("the models normalise their input differently (metadata mean/std "
                            f"differ: {sorted(norm, key=str)})")
    h, w = max((s for _, _, s, _ in members), key=lambda s: (s[0] * s[1], s))
    if any(s[0] > h or s[1] > w for _, _, s, _ in members):
        raise EnsembleError("the members' input sizes do not nest (one is not the largest in "
                            "both height and width): "
                            + ", ".join(f"{s[1]}x{s[0]}" for _, _, s, _ in members))
    total = sum(weights)
    nodes, inits, info = [], [], []
    for i, ((m, meta, (mh, mw), dim), wt, p) in enumerate(
            zip(members, weights, paths, strict=True)):
        _weights_as_float32(m.graph)
        if _opset(m) < OPSET and any(n.op_type in CHANGED_BY_18 for n in m.graph.node):
            from onnx import version_converter

            try:
                m = version_converter.convert_version(m, OPSET)
            except Exception as e:  # the converter raises its own and RuntimeError types
                raise EnsembleError(f"{p}: cannot convert its opset {_opset(m)} to {OPSET} "
                                    f"({type(e).__name__})") from None
        elif _opset(m) > OPSET:
            raise EnsembleError(f"{p}: opset {_opset(m)}; an ensemble is opset {OPSET}")
        opset = _opset(m)
        pre = f"m{i}/"
        m = compose.add_prefix(m, pre)
        g = m.graph
        src, out = g.input[0].name, g.output[0].name
        if (mh, mw) == (h, w):
            nodes.append(helper.make_node("Identity", ["images"], [src], name=pre + "input"))
        else:
            inits.append(numpy_helper.from_array(np.array([mh, mw], np.int64), pre + "size"))
            nodes.append(helper.make_node("Resize", ["images", "", "", pre + "size"], [src],
                                          name=pre + "resize", mode="linear", antialias=1,
                                          axes=[2, 3],
                                          coordinate_transformation_mode="half_pixel"))
        nodes.extend(g.node)
        inits.extend(g.initializer)
        scale = np.float32(np.sqrt(wt / total))
        inits.extend([numpy_helper.from_array(np.array([1], np.int64), pre + "axis"),
                      numpy_helper.from_array(np.float32(1e-12), pre + "eps"),
                      numpy_helper.from_array(scale, pre + "weight")])
        nodes.extend([
            helper.make_node("ReduceL2", [out, pre + "axis"], [pre + "norm"], keepdims=1,
                             name=pre + "norm"),
            helper.make_node("Max", [pre + "norm", pre + "eps"], [pre + "norm_eps"],
                             name=pre + "norm_eps"),
            helper.make_node("Div", [out, pre + "norm_eps"], [pre + "unit"], name=pre + "unit"),
            helper.make_node("Mul", [pre + "unit", pre + "weight"], [pre + "scaled"],
                             name=pre + "scaled")])
        info.append({"file": p.name, "model": meta.get("model"), "input_height": mh,
                     "input_width": mw, "feature_dim": dim, "weight": wt,
                     "sha256": hashlib.sha256(p.read_bytes()).hexdigest(),
                     "opset": opset, "input": src[len(pre):],
                     "output": out[len(pre):], "metadata": meta})
    dim = sum(d for _, _, _, d in members)
    nodes.append(helper.make_node("Concat", [f"m{i}/scaled" for i in range(len(members))],
                                  ["embedding"], axis=1, name="concat"))
    graph = helper.make_graph(
        nodes, "dashtraj_reid_ensemble",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, ["batch", 3, h, w])],
        [helper.make_tensor_value_info("embedding", TensorProto.FLOAT, ["batch", dim])],
        initializer=inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)],
                              producer_name="dashtraj reid ensemble")
    model.ir_version = min(model.ir_version, 9)
    if int8:
        n_q = _store_int8(model.graph)
        dtype = "int8 per output channel"
    else:
        from dashtraj.train.reid_export import fp16_weights  # torch-free, as this module

        n_q = fp16_weights(model)
        dtype = "float16"
    try:
        onnx.checker.check_model(model)
    except onnx.checker.ValidationError as e:
        raise EnsembleError("the joined graph is not valid ONNX: "
                            + str(e).strip().splitlines()[0]) from None
    first = members[0][1]
    meta = {"model": "ensemble(" + ", ".join(f"{x['model']}@{x['input_height']}"
                                            for x in info) + ")",
            "ensemble": json.dumps(info), "input_height": str(h), "input_width": str(w),
            "mean": first.get("mean", "[0.485, 0.456, 0.406]"),
            "std": first.get("std", "[0.229, 0.224, 0.225]"), "feature_dim": str(dim),
            "weights_dtype": dtype, "weights": f"{dtype} storage of {n_q} tensors, float32 "
                                                "inference"}
    _save(model, meta, output)
    return meta


def extract_member(path, index: int, output) -> dict:
    """Member ``index`` (1-based) of an ensemble written back as a standalone ReID model at
    ``output``: its nodes and weights (float32, as the ensemble stores them: an int8
    ensemble's member differs from the file it was built from by the rounding), its input
    size, opset and metadata. `reid eval` scores it alone; `reid train --init` trains it on.

    Returns the member's metadata as written. Raises EnsembleError: not an ensemble, no
    such member, or an ensemble written before members kept their metadata.
    """
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    path = Path(path)
    m, meta = _load(path)
    if "ensemble" not in meta:
        raise EnsembleError(f"{path}: not an ensemble of 'dashtraj reid ensemble'")
    members = json.loads(meta["ensemble"])
    if not 1 <= index <= len(members):
        raise EnsembleError(f"member {index}: {path} has members 1 to {len(members)}")
    info = members[index - 1]
    if "metadata" not in info:
        raise EnsembleError(f"{path}: written before ensembles kept their members' metadata; "
                            "build it again from the members")
    pre = f"m{index - 1}/"
    g = m.graph
    raw = {i.name: numpy_helper.to_array(i) for i in g.initializer if i.name.startswith(pre)}
    weights = {}
    for name, arr in raw.items():  # the storage of `_store_int8` / `fp16_weights`
        if name.endswith("__int8"):
            base = name[:-len("__int8")]
            weights[base] = arr.astype(np.float32) * raw[base + "__scale"]
        elif name.endswith("__fp16"):
            weights[name[:-len("__fp16")]] = arr.astype(np.float32)
        elif not name.endswith("__scale"):
            weights[name] = arr
    src, out = pre + info["input"], pre + info["output"]
    added = {src, pre + "norm", pre + "norm_eps", pre + "unit", pre + "scaled"}
    nodes = [n for n in g.node if n.output and all(o.startswith(pre) for o in n.output)
             and not any(o in added or o in weights or o.endswith("__float")
                         for o in n.output)]
    used = {i for n in nodes for i in n.input}

    def bare(name: str) -> str:
        return name[len(pre):] if name.startswith(pre) else name

    for n in nodes:
        n.input[:] = [bare(i) for i in n.input]
        n.output[:] = [bare(o) for o in n.output]
        n.name = bare(n.name)
    graph = helper.make_graph(
        nodes, "dashtraj_reid_member",
        [helper.make_tensor_value_info(bare(src), TensorProto.FLOAT,
                                       ["batch", 3, info["input_height"], info["input_width"]])],
        [helper.make_tensor_value_info(bare(out), TensorProto.FLOAT,
                                       ["batch", info["feature_dim"]])],
        initializer=[numpy_helper.from_array(np.asarray(a), bare(k))
                     for k, a in weights.items() if k in used])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", info["opset"])],
                              producer_name="dashtraj reid member")
    model.ir_version = min(model.ir_version, 8)
    onnx.checker.check_model(model)
    mmeta = {**info["metadata"], "weights_dtype": "float32",
             "weights": f"float32, member {index} of {path.name} ({meta.get('weights_dtype')} "
                        "there)"}
    _save(model, mmeta, output)
    return mmeta
