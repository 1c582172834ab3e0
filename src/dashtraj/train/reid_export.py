"""ONNX export of a trained ReID checkpoint (needs the ``.[train]`` extra: torch).

The ONNX graph maps ``images`` (N, 3, H, W) float32, normalised as
``dashtraj.reid.preprocess``, to ``embedding`` (N, 512) float32 (not L2-normalised; the
run time normalises). The batch axis is dynamic; H and W are fixed to the training
input. Metadata properties: ``model``, ``input_height``, ``input_width``, ``mean``,
``std`` (JSON lists), ``feature_dim``, ``recipe`` (JSON), ``weights_dtype``.

``fp16_weights`` stores every large float32 weight tensor as float16 followed by a
``Cast`` back to float32: the file is half the size, onnxruntime folds the casts when it
loads the model (the arithmetic stays float32, at float32 speed), and the weights are
rounded to float16 (relative error ≤ 2⁻¹¹; embeddings move by about 1e-3).
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

from dashtraj.errors import DashtrajError
from dashtraj.reid.preprocess import IMAGENET_MEAN, IMAGENET_STD


class ExportError(DashtrajError):
    """A checkpoint cannot be exported; the message names the file."""


def load_checkpoint(path: str | Path):
    """(model in eval mode, checkpoint dict) from a ``best.pt`` / ``last.pt`` of a run."""
    import torch

    from dashtraj.reid.models import build_model

    p = Path(path)
    if not p.is_file():
        raise ExportError(f"{p}: no such checkpoint")
    try:
        ck = torch.load(p, map_location="cpu", weights_only=False)
    except Exception as e:  # a pickle or zip error of any kind: not a checkpoint
        raise ExportError(f"{p}: not a torch checkpoint ({type(e).__name__}: {e})") from e
    try:
        recipe = ck["recipe"]
        model = build_model(recipe["model"], int(ck["num_classes"]), pretrained=False)
        model.load_state_dict(ck["model"])
    except KeyError as e:
        raise ExportError(f"{p}: not a dashtraj ReID checkpoint (no {e} entry: give a run's "
                          "best.pt or last.pt)") from e
    except (TypeError, RuntimeError, OSError, ValueError) as e:
        raise ExportError(f"{p}: not a dashtraj ReID checkpoint ({e})") from e
    return model.eval(), ck


def fp16_weights(model, min_elements: int = 1024) -> int:
    """Store the float32 initializers of an ``onnx.ModelProto`` with at least
    `min_elements` elements as float16 + ``Cast`` to float32 (in place); returns how many."""
    import numpy as np
    from onnx import TensorProto, helper, numpy_helper

    graph = model.graph
    keep, casts, n = [], [], 0
    for init in graph.initializer:
        if init.data_type != TensorProto.FLOAT or np.prod(init.dims) < min_elements:
            keep.append(init)
            continue
        half = numpy_helper.from_array(numpy_helper.to_array(init).astype(np.float16),
                                       init.name + "__fp16")
        keep.append(half)
        casts.append(helper.make_node("Cast", [half.name], [init.name], to=TensorProto.FLOAT,
                                      name=init.name + "__cast"))
        n += 1
    del graph.initializer[:]
    graph.initializer.extend(keep)
    nodes = casts + list(graph.node)
    del graph.node[:]
    graph.node.extend(nodes)
    return n


def export_onnx(checkpoint: str | Path, out_path: str | Path, opset: int = 17,
                fp16: bool = False) -> dict:
    """Write the embedding network of a checkpoint as ONNX; returns its metadata dict.
    `fp16`: store the weights as float16 (module docstring)."""
    import onnx
    import torch

    model, ck = load_checkpoint(checkpoint)
    recipe = ck["recipe"]
    h, w = int(recipe["height"]), int(recipe["width"])
    meta = {"model": recipe["model"], "input_height": str(h), "input_width": str(w),
            "mean": json.dumps(list(IMAGENET_MEAN)), "std": json.dumps(list(IMAGENET_STD)),
            "feature_dim": "512", "recipe": json.dumps(recipe, sort_keys=True),
            "epoch": str(ck.get("epoch", "")), "weights_dtype": "float16" if fp16 else "float32"}
    out_path = Path(out_path)
    model = model.to(memory_format=torch.contiguous_format)
    x = torch.zeros(2, 3, h, w)
    with warnings.catch_warnings():  # the TorchScript exporter is deprecated, not removed;
        # it needs no onnxscript (the torch.export-based exporter does)
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.onnx.export(model, (x,), str(out_path), input_names=["images"],
                          output_names=["embedding"], opset_version=opset, dynamo=False,
                          dynamic_axes={"images": {0: "batch"}, "embedding": {0: "batch"}},
                          do_constant_folding=True)
    m = onnx.load(str(out_path))
    if fp16:
        fp16_weights(m)
    for k, v in meta.items():
        prop = m.metadata_props.add()
        prop.key, prop.value = k, v
    onnx.save(m, str(out_path))
    return meta
