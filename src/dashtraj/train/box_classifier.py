"""Train the detector's second stage: a crop classifier of the 15 detection classes.

The detector (`dashtraj.train.detector_model`) finds vehicles well and names them less well:
on the held-out renders its boxes scored class-agnostic reach a mAP50 (boxes ≥ 24 px) well
above its 15-class figure, and given each box's true class they would reach more than that
(README, "Vehicle detector"). Its class branch reads 8-32 px strided features of a mostly
frozen backbone. This stage looks at each box's own pixels instead: the box grown by
``MARGIN`` on every side, squashed to ``CROP_PX`` square, its centre ``INPUT_PX`` square
(drawn at random in training, the middle at run time) into the stem and first ``BLOCKS``
blocks of an EfficientNet-Lite0 (ImageNet start, every layer trained; 11 blocks end at its
112-channel stage: 0.7 M parameters, a 1.4 MB ONNX), global average pooling, dropout and one
linear layer. The 11 blocks were chosen on the set's validation boxes: accuracy 0.863 against
0.850 with all 16 blocks (a 5.9 MB ONNX, which with the detector's 6.3 MB would pass the
12 MB that the detector issue allows) and 0.848 with 15 after 6 of 8 epochs.

Data: every labelled box of a set made by ``dashtraj detection-dataset`` (its split by
recording). Augmentation: the random centre (a box's position and size off by up to
``(CROP_PX - INPUT_PX) / CROP_PX`` of the crop), horizontal flips (a crop's class and
orientation survive a mirror: ``side`` says neither left nor right, and a crop carries no
traffic side, unlike a whole frame), brightness and contrast. Softmax cross-entropy with
label smoothing 0.1, AdamW, cosine from ``lr`` with 200 steps of warm-up.

Deterministic for a seed and thread count (each epoch's order and draws come from
``seed`` and the epoch; a resumed run repeats them). Needs the training extra (torch).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

CROP_PX = 76
INPUT_PX = 64
MARGIN = 0.25
BLOCKS = 11
MEAN = (0.485, 0.456, 0.406)
STD = (0.229, 0.224, 0.225)


def extract_crops(data, crop_px: int = CROP_PX, margin: float = MARGIN) -> dict:
    """Every labelled box of a YOLO set as a crop: {"x": (N, crop_px, crop_px, 3) uint8,
    "y": (N,) class, "split": (N,) 0 train / 1 val, "height": (N,) box height, pixels,
    "names": class names}. Crops are made as `dashtraj.perception.detect.box_crops` makes
    them at run time (before its centre cut)."""
    from PIL import Image

    from dashtraj.perception.detect import box_crops, read_names_yaml

    root = Path(data)
    names = read_names_yaml(root / "data.yaml")
    xs, ys, splits, hs = [], [], [], []
    for k, split in enumerate(("train", "val")):
        for lab in sorted((root / "labels" / split).glob("*.txt")):
            rows = [r.split() for r in lab.read_text(encoding="utf-8").splitlines() if r.strip()]
            if not rows:
                continue
            img = np.asarray(Image.open(root / "images" / split / (lab.stem + ".jpg"))
                             .convert("RGB"))
            hh, ww = img.shape[:2]
            lab_rows = np.array([[float(v) for v in r[:5]] for r in rows])
            cx, cy, w, h = (lab_rows[:, 1] * ww, lab_rows[:, 2] * hh, lab_rows[:, 3] * ww,
                            lab_rows[:, 4] * hh)
            boxes = np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], 1)
            xs.append(box_crops(img, boxes, margin, crop_px, crop_px))
            ys.append(lab_rows[:, 0].astype(np.int64))
            splits.append(np.full(len(rows), k, np.int64))
            hs.append(h)
    if not xs:
        raise ValueError(f"{root}: no labelled boxes in labels/train or labels/val")
    return {"x": np.concatenate(xs), "y": np.concatenate(ys), "split": np.concatenate(splits),
            "height": np.concatenate(hs), "names": names}


def build_net(num_classes: int, pretrained: bool = True, blocks: int = BLOCKS):
    """The classifier network: the Lite0 stem and its first ``blocks`` blocks (of 16),
    global average pooling, dropout 0.2, one linear layer."""
    import torch.nn as nn
    import torch.nn.functional as F

    from dashtraj.train.detector_model import EfficientNetLite0

    class BoxClassifierNet(nn.Module):
        def __init__(self):
            super().__init__()
            self.trunk = EfficientNetLite0()
            if pretrained:
                self.trunk.load_pretrained()
            self.trunk._blocks = self.trunk._blocks[:blocks]
            self.drop = nn.Dropout(0.2)
            self.fc = nn.Linear(self.trunk._blocks[-1]._project_conv.out_channels, num_classes)

        def forward(self, x):
            t = self.trunk
            x = F.relu6(t._bn0(t._conv_stem(x)))
            for b in t._blocks:
                x = b(x)
            return self.fc(self.drop(x.mean((2, 3))))

    return BoxClassifierNet()


def _batch(x: np.ndarray, input_px: int, rng: np.random.Generator | None):
    """uint8 crops → normalised (B, 3, input_px, input_px) float tensor: the centre, or
    with ``rng`` a random square of input_px-6 .. crop px at a random place (rescaled),
    flipped half the time, brightness × 0.7-1.3 and ± 0.05."""
    import torch
    import torch.nn.functional as F

    t = torch.from_numpy(np.ascontiguousarray(x)).permute(0, 3, 1, 2).float() / 255.0
    n, _, s, _ = t.shape
    if rng is None:
        o = (s - input_px) // 2
        t = t[:, :, o:o + input_px, o:o + input_px]
    else:
        out = torch.empty(n, 3, input_px, input_px)
        for i in range(n):
            c = int(rng.integers(input_px - 6, s + 1))
            ox, oy = int(rng.integers(0, s - c + 1)), int(rng.integers(0, s - c + 1))
            patch = t[i:i + 1, :, oy:oy + c, ox:ox + c]
            if rng.random() < 0.5:
                patch = patch.flip(3)
            out[i] = F.interpolate(patch, size=(input_px, input_px), mode="bilinear",
                                   align_corners=False)[0]
        gain = torch.from_numpy(rng.uniform(0.7, 1.3, (n, 1, 1, 1))).float()
        bias = torch.from_numpy(rng.uniform(-0.05, 0.05, (n, 1, 1, 1))).float()
        t = (out * gain + bias).clamp(0, 1)
    mean = torch.tensor(MEAN).view(1, 3, 1, 1)
    std = torch.tensor(STD).view(1, 3, 1, 1)
    return (t - mean) / std


def evaluate(net, x: np.ndarray, y: np.ndarray, input_px: int = INPUT_PX) -> dict:
    """Accuracy of the 15 classes, of the vehicle class alone (class // 3) and of the
    orientation alone (class % 3) on centre crops."""
    import torch

    net.eval()
    pred = []
    with torch.no_grad():
        for i in range(0, len(x), 256):
            pred.append(net(_batch(x[i:i + 256], input_px, None)).argmax(1).numpy())
    p = np.concatenate(pred) if pred else np.zeros(0, np.int64)
    n = max(len(y), 1)
    return {"acc": float((p == y).sum() / n), "vehicle_acc": float((p // 3 == y // 3).sum() / n),
            "orientation_acc": float((p % 3 == y % 3).sum() / n), "n": len(y)}


def train(data, out, epochs: int = 8, seed: int = 0, threads: int = 2, lr: float = 1e-3,
          batch: int = 64, input_px: int = INPUT_PX, blocks: int = BLOCKS, log=print) -> dict:
    """Train on a YOLO set's boxes; writes OUT/last.pt after every epoch (a rerun resumes
    from it), OUT/log.jsonl (one line per epoch: loss, validation accuracies, wall time)
    and OUT/crops.npz (the extracted crops, reused by a resumed run). Returns the last
    epoch's line plus ``names``."""
    import torch
    import torch.nn.functional as F

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(threads)
    cache = out / "crops.npz"
    if cache.is_file():
        z = np.load(cache, allow_pickle=False)
        d = {k: z[k] for k in ("x", "y", "split", "height")}
        d["names"] = json.loads(str(z["names"]))
    else:
        d = extract_crops(data)
        tmp = out / "crops.tmp.npz"
        np.savez(tmp, **{k: d[k] for k in ("x", "y", "split", "height")},
                 names=np.array(json.dumps(d["names"])))
        tmp.replace(cache)
    names = list(d["names"])
    tr, va = np.flatnonzero(d["split"] == 0), np.flatnonzero(d["split"] == 1)
    torch.manual_seed(seed)
    net = build_net(len(names), blocks=blocks).to(memory_format=torch.channels_last)
    opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=5e-4)
    per_epoch = len(tr) // batch
    total = max(1, epochs * per_epoch)
    start, wall0 = 0, 0.0
    ckpt = out / "last.pt"
    if ckpt.is_file():
        state = torch.load(ckpt, map_location="cpu", weights_only=False)
        if (int(state.get("blocks", BLOCKS)), int(state["input_px"])) != (blocks, input_px):
            from dashtraj.errors import DashtrajError

            raise DashtrajError(f"{ckpt}: trained with {state.get('blocks', BLOCKS)} blocks at "
                                f"{state['input_px']} px, not {blocks} at {input_px}; resume "
                                "with those or train into another folder")
        net.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        start, wall0 = state["epoch"] + 1, state["wall_s"]
    t0 = time.time()
    done = (out / "log.jsonl").read_text(encoding="utf-8").splitlines() \
        if (out / "log.jsonl").is_file() else []
    line: dict = json.loads(done[-1]) if done else {}
    for ep in range(start, epochs):
        rng = np.random.default_rng([seed, ep])
        torch.manual_seed(seed * 1000 + ep)
        net.train()
        perm = rng.permutation(tr)
        losses = []
        for i in range(per_epoch):
            step = ep * per_epoch + i
            f = min(1.0, (step + 1) / 200) * 0.5 * (1 + math.cos(math.pi * step / total))
            for g in opt.param_groups:
                g["lr"] = lr * f
            idx = perm[i * batch:(i + 1) * batch]
            x = _batch(d["x"][idx], input_px, rng).contiguous(memory_format=torch.channels_last)
            loss = F.cross_entropy(net(x), torch.from_numpy(d["y"][idx]), label_smoothing=0.1)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(loss.item())
        line = {"epoch": ep + 1, "loss": float(np.mean(losses)) if losses else None,
                "val": evaluate(net, d["x"][va], d["y"][va], input_px),
                "wall_s": wall0 + time.time() - t0}
        log(json.dumps(line))
        with open(out / "log.jsonl", "a", encoding="utf-8") as fh:
            fh.write(json.dumps(line) + "\n")
        tmp = out / "last.tmp.pt"
        torch.save({"model": net.state_dict(), "optimizer": opt.state_dict(), "epoch": ep,
                    "wall_s": line["wall_s"], "names": names, "input_px": input_px,
                    "blocks": blocks,
                    "seed": seed, "threads": threads}, tmp)
        tmp.replace(ckpt)
    return {**line, "names": names}


def export_onnx(checkpoint, path, fp16_weights: bool = True) -> None:
    """Write a checkpoint's classifier as ONNX: input ``images`` (N, 3, S, S), output
    ``logits`` (N, C); metadata ``names`` (JSON list), ``crop_px``, ``input_px``,
    ``margin`` (what `dashtraj.perception.detect.BoxClassifier` reads)."""
    import warnings

    import onnx
    import torch

    from dashtraj.train.detector_model import finish_onnx

    state = torch.load(checkpoint, map_location="cpu", weights_only=False)
    names, s = state["names"], int(state["input_px"])
    net = build_net(len(names), pretrained=False, blocks=int(state.get("blocks", BLOCKS)))
    net.load_state_dict(state["model"])
    net.eval()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.onnx.export(net, (torch.zeros(1, 3, s, s),), str(path), input_names=["images"],
                          output_names=["logits"], opset_version=17,
                          dynamic_axes={"images": {0: "batch"}, "logits": {0: "batch"}},
                          dynamo=False)
    m = onnx.load(str(path))
    info = {"names": json.dumps(names), "crop_px": str(CROP_PX), "input_px": str(s),
            "margin": str(MARGIN), "description": "dashtraj box classifier (detector stage 2)"}
    finish_onnx(m, path, info, fp16_weights)
