"""A ReID network's training weights recovered from its exported ONNX (torch).

`dashtraj reid export` folds every BatchNorm into the convolution before it, drops the
identity classifier and may store the weights as float16, so a shipped ONNX is not a
training checkpoint. `init_from_onnx` rebuilds one from it, so that training can go on
from the shipped model (a larger input, another augmentation, a GPU) without the run folder
that produced it:

1. The convolutions are matched in forward order (torch's, traced on one input, against the
   ONNX graph's nodes, which the export traced in the same order) and their shapes checked;
   every other tensor the ONNX names as in the state dict (the head's Linear and
   BatchNorm1d) is copied.
2. A folded pair (a convolution whose output goes straight into a BatchNorm2d) gets the
   folded weight W and bias b back as: convolution W, BatchNorm running mean μ and variance
   σ² of W·x over the calibration images, γ = √(σ² + ε), β = μ + b. In eval mode that is
   exactly W·x + b (the ONNX's), and in training mode, where a BatchNorm normalises by its
   batch's statistics, nearly so (the batch's μ, σ are those of the calibration images).
3. The rebuilt network's embeddings are checked against onnxruntime's on the calibration
   images (cosine ≥ 0.999, the float16 weights' rounding): a mismatch raises `TrainError`.
4. The classifier, which no ONNX keeps, starts as the unit mean embedding of each identity's
   images (``per_class`` of them), scaled so that the median image gives logits of ±10 (a
   nearest-class-mean classifier), and is then fitted on the embeddings of every training
   image (``fit_classifier``: full-batch L-BFGS on the label-smoothed cross-entropy, the
   rest of the network fixed), so training goes on from a trained head as it would from a
   checkpoint, not from a loss of ln N.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dashtraj.reid.train import TrainError, embed_array


def _onnx_tensors(path: Path):
    """(convolutions in node order as (weight, bias or None), {name: array} of every
    initializer under its torch name, metadata)."""
    import onnx
    from onnx import numpy_helper

    try:
        m = onnx.load(str(path))
    except Exception as e:  # onnx raises DecodeError, OSError and others alike
        raise TrainError(f"--init: {path}: not an ONNX model ({type(e).__name__})") from None
    meta = {p.key: p.value for p in m.metadata_props}
    if "ensemble" in meta:
        raise TrainError(f"--init: {path} is an ensemble ({meta.get('model')}); start from one "
                         f"of its members ('dashtraj reid member {path.name} N -o M.onnx')")
    raw = {i.name: numpy_helper.to_array(i) for i in m.graph.initializer}
    # float16 weights reach their node through a Cast (`reid export --fp16-weights`)
    alias = {n.output[0]: n.input[0] for n in m.graph.node
             if n.op_type == "Cast" and n.input[0] in raw}

    def value(name):
        return raw[alias.get(name, name)].astype(np.float32)

    named = {alias_name: value(alias_name) for alias_name in [*raw, *alias]
             if not alias_name.endswith("__fp16")}
    convs = [(value(n.input[1]), value(n.input[2]) if len(n.input) > 2 and n.input[2] else None)
             for n in m.graph.node if n.op_type == "Conv"]
    return convs, named, meta


def onnx_input_size(meta: dict, height: int, width: int) -> tuple[int, int]:
    """The (height, width) an exported model takes (its metadata; else the given size)."""
    return int(meta.get("input_height", height)), int(meta.get("input_width", width))


def check_onnx(path: str | Path, model_name: str, height: int, width: int,
               any_size: bool = False):
    """`_onnx_tensors` of an ONNX that `init_from_onnx` can take for ``model_name`` at
    ``height`` × ``width`` (``any_size``: an ONNX exported at another input size too; the
    networks end in global pooling, so the weights fit any size, and training at the new
    size adapts them). Raises TrainError otherwise (before a run folder is touched)."""
    path = Path(path)
    convs, named, meta = _onnx_tensors(path)
    if not convs:
        raise TrainError(f"--init: {path} has no convolutions: not a ReID network")
    if meta.get("model") not in (None, model_name):
        raise TrainError(f"--init: {path} is a {meta['model']}; this run trains a {model_name}")
    size = onnx_input_size(meta, height, width)
    if size != (height, width) and not any_size:
        raise TrainError(f"--init: {path} takes {size[0]}x{size[1]} images; this recipe "
                         f"trains at {height}x{width} (--size {width}x{height} fine-tunes it "
                         "at that size)")
    return convs, named, meta


def _conv_bn_pairs(model, height: int, width: int):
    """The model's Conv2d modules in forward order, each with the BatchNorm2d that takes
    its output directly (or None)."""
    import torch
    from torch import nn

    order, out_of, bn_of = [], {}, {}
    hooks = []
    for mod in model.modules():
        if isinstance(mod, nn.Conv2d):
            def fc(m, _inp, out):
                order.append(m)
                out_of[id(out)] = m
            hooks.append(mod.register_forward_hook(fc))
        elif isinstance(mod, nn.BatchNorm2d):
            def fb(m, inp, _out):
                c = out_of.get(id(inp[0]))
                if c is not None:
                    bn_of[c] = m
            hooks.append(mod.register_forward_hook(fb))
    was = model.training
    model.eval()
    try:
        with torch.no_grad():
            model(torch.zeros(1, 3, height, width))
    finally:
        for h in hooks:
            h.remove()
        model.train(was)
    return [(c, bn_of.get(c)) for c in order]


def _fit_classifier(model, feats: np.ndarray, labels: np.ndarray, label_smoothing: float,
                    iters: int) -> tuple[float, float, float]:
    """The classifier fitted on fixed embeddings (full-batch L-BFGS); returns the loss
    before and after, and the training accuracy after."""
    import torch
    import torch.nn.functional as F

    clf = model.head.classifier
    v = torch.from_numpy(feats)
    y = torch.from_numpy(np.asarray(labels, np.int64))
    opt = torch.optim.LBFGS(clf.parameters(), lr=1.0, max_iter=iters,
                            line_search_fn="strong_wolfe")

    def loss_fn():
        opt.zero_grad()
        loss = F.cross_entropy(clf(v), y, label_smoothing=label_smoothing)
        loss.backward()
        return loss

    with torch.no_grad():
        before = float(F.cross_entropy(clf(v), y, label_smoothing=label_smoothing))
    opt.step(loss_fn)
    with torch.no_grad():
        logits = clf(v)
        after = float(F.cross_entropy(logits, y, label_smoothing=label_smoothing))
        acc = float((logits.argmax(1) == y).float().mean())
    return before, after, acc


def init_from_onnx(model, path: str | Path, images: np.ndarray, labels: np.ndarray,
                   model_name: str, height: int, width: int, per_class: int = 4,
                   calib_images: int = 512, fit_classifier: bool = True,
                   label_smoothing: float = 0.1, fit_iters: int = 100, seed: int = 0,
                   any_size: bool = False, log=print) -> dict:
    """Fill ``model`` (a `ReidNet` of ``model_name`` built for ``labels``' classes, on the
    CPU) from the ONNX at ``path`` (module docstring). ``images`` (N, H, W, 3) uint8 at the
    model's input size and ``labels`` (N,) class indices are the training images; up to
    ``calib_images`` of them calibrate the BatchNorms and ``per_class`` per class set the
    classifier. Returns what was done (counts, the check's worst cosine).

    ``any_size``: the ONNX may take another input size (`check_onnx`); the BatchNorms are
    then calibrated on the images at the training size, and the check against onnxruntime
    runs on the calibration images resized to the ONNX's size (in eval mode the rebuilt
    network is the exported one at any size).

    Raises TrainError: not an ONNX of ``model_name`` at ``height`` × ``width``, a network
    whose layers do not match, or embeddings that do not match onnxruntime's."""
    import torch

    from dashtraj.reid.embed import ReidEmbedder

    path = Path(path)
    convs, named, meta = check_onnx(path, model_name, height, width, any_size=any_size)
    onnx_size = onnx_input_size(meta, height, width)
    pairs = _conv_bn_pairs(model, height, width)
    if len(pairs) != len(convs):
        raise TrainError(f"--init: {path} has {len(convs)} convolutions, a {model_name} "
                         f"{len(pairs)}")
    rng = np.random.default_rng(seed)
    calib = np.sort(rng.choice(len(images), min(calib_images, len(images)), replace=False))
    x_cal = np.asarray(images[calib])
    sd = model.state_dict()
    copied = 0
    with torch.no_grad():
        for k, (w, b) in enumerate(convs):
            conv, bn = pairs[k]
            if tuple(conv.weight.shape) != w.shape:
                raise TrainError(f"--init: {path}: convolution {k} is {w.shape}, the "
                                 f"{model_name}'s {tuple(conv.weight.shape)}")
            conv.weight.copy_(torch.from_numpy(w))
            b = np.zeros(w.shape[0], np.float32) if b is None else b
            if bn is not None:  # folded: exact in eval mode until calibrated below
                bn.running_mean.zero_()
                bn.running_var.fill_(1.0 - bn.eps)
                bn.weight.fill_(1.0)
                bn.bias.copy_(torch.from_numpy(b))
            elif conv.bias is not None:
                conv.bias.copy_(torch.from_numpy(b))
            elif np.any(b != 0):
                raise TrainError(f"--init: {path}: convolution {k} has a bias the "
                                 f"{model_name}'s has no place for")
        for name, t in sd.items():
            if name in named and tuple(t.shape) == named[name].shape:
                t.copy_(torch.from_numpy(named[name]))
                copied += 1
        # 2. calibrate the folded BatchNorms: statistics of each convolution's output
        stats: dict = {}
        hooks = []
        for conv, bn in pairs:
            if bn is None:
                continue

            def hook(m, _inp, out, bn=bn):
                o = out.double()
                s = stats.setdefault(bn, [0, 0.0, 0.0])
                s[0] += o.numel() // o.shape[1]
                s[1] = s[1] + o.sum((0, 2, 3))
                s[2] = s[2] + (o * o).sum((0, 2, 3))
            hooks.append(conv.register_forward_hook(hook))
        try:
            embed_array(model, x_cal, False)
        finally:
            for h in hooks:
                h.remove()
        for bn, (n, s1, s2) in stats.items():
            mu = s1 / n
            var = (s2 / n - mu * mu).clamp_min(0.0)
            b = bn.bias.double().clone()
            bn.running_mean.copy_(mu)
            bn.running_var.copy_(var)
            bn.weight.copy_((var + bn.eps).sqrt())
            bn.bias.copy_(mu + b)
    # 3. the check against onnxruntime, at the ONNX's own input size
    x_chk = x_cal
    if onnx_size != (height, width):
        from dashtraj.reid.preprocess import resize_uint8

        x_chk = np.stack([resize_uint8(a, *onnx_size) for a in x_cal])
    ours = embed_array(model, x_chk, False)
    ours /= np.linalg.norm(ours, axis=1, keepdims=True) + 1e-12
    ref = ReidEmbedder(path, threads=1).embed(list(x_chk))
    cos = float(np.min(np.sum(ours * ref, axis=1)))
    if cos < 0.999:
        raise TrainError(f"--init: {path}: the rebuilt {model_name} embeds the calibration "
                         f"images differently from onnxruntime (worst cosine {cos:.4f})")
    # 4. the classifier: each class's unit mean embedding, then fitted
    labels = np.asarray(labels)
    if fit_classifier:
        log(f"embedding {len(images)} training images to fit the classifier ...")
        v_all = embed_array(model, images, False)
    pick = []
    for c in range(model.head.classifier.out_features):
        idx = np.flatnonzero(labels == c)
        if len(idx):
            pick.extend(rng.choice(idx, min(per_class, len(idx)), replace=False).tolist())
    pick = np.sort(np.asarray(pick, np.int64))
    v = v_all[pick] if fit_classifier else embed_array(model, images[pick], False)
    norm = float(np.median(np.linalg.norm(v, axis=1)))
    w = np.zeros((model.head.classifier.out_features, v.shape[1]), np.float32)
    np.add.at(w, labels[pick], v)
    w /= np.linalg.norm(w, axis=1, keepdims=True) + 1e-12
    with torch.no_grad():
        model.head.classifier.weight.copy_(torch.from_numpy(w * (10.0 / max(norm, 1e-6))))
        model.head.classifier.bias.zero_()
    info = {"onnx": str(path), "convolutions": len(convs),
            "folded_batchnorms": len(stats), "tensors_copied": copied,
            "calibration_images": len(x_cal), "classifier_images": len(pick),
            "onnx_size": list(onnx_size), "size": [height, width],
            "worst_cosine": round(cos, 6)}
    if fit_classifier:
        before, after, acc = _fit_classifier(model, v_all, labels, label_smoothing,
                                             fit_iters)
        info.update(classifier_images=len(v_all), classifier_loss=[round(before, 4),
                                                                   round(after, 4)],
                    classifier_train_acc=round(acc, 4))
        log(f"classifier fitted on {len(v_all)} embeddings: loss {before:.3f} -> "
            f"{after:.3f}, train accuracy {acc:.3f}")
    log(f"initialised from {path}: {len(convs)} convolutions ({len(stats)} BatchNorms "
        f"recalibrated on {len(x_cal)} images), worst cosine to onnxruntime {cos:.5f}")
    return info
