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


def _labelled_images(root: Path):
    """Every image of a YOLO set's train and val splits with its labels: yields (split index
    0 train / 1 val, index within the split, split name, (H, W, 3) uint8 RGB image, (K,)
    classes, (K, 4) boxes x0, y0, x1, y1 in image pixels, (K,) their heights as labelled),
    in file order."""
    from PIL import Image

    for k, split in enumerate(("train", "val")):
        for n, lab in enumerate(sorted((root / "labels" / split).glob("*.txt"))):
            rows = [r.split() for r in lab.read_text(encoding="utf-8").splitlines() if r.strip()]
            img = np.asarray(Image.open(root / "images" / split / (lab.stem + ".jpg"))
                             .convert("RGB"))
            hh, ww = img.shape[:2]
            lr = np.array([[float(v) for v in r[:5]] for r in rows]).reshape(-1, 5)
            cx, cy, w, h = lr[:, 1] * ww, lr[:, 2] * hh, lr[:, 3] * ww, lr[:, 4] * hh
            yield (k, n, split, img, lr[:, 0].astype(np.int64),
                   np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], 1), h)


def extract_crops(data, crop_px: int = CROP_PX, margin: float = MARGIN) -> dict:
    """Every labelled box of a YOLO set as a crop: {"x": (N, crop_px, crop_px, 3) uint8,
    "y": (N,) class, "split": (N,) 0 train / 1 val, "height": (N,) box height, pixels,
    "names": class names}. Crops are made as `dashtraj.perception.detect.box_crops` makes
    them at run time (before its centre cut)."""
    from dashtraj.perception.detect import box_crops, read_names_yaml

    root = Path(data)
    names = read_names_yaml(root / "data.yaml")
    xs, ys, splits, hs = [], [], [], []
    for k, _, _, img, cls, boxes, heights in _labelled_images(root):
        if not len(cls):
            continue
        xs.append(box_crops(img, boxes, margin, crop_px, crop_px))
        ys.append(cls)
        splits.append(np.full(len(cls), k, np.int64))
        hs.append(heights)
    if not xs:
        raise ValueError(f"{root}: no labelled boxes in labels/train or labels/val")
    return {"x": np.concatenate(xs), "y": np.concatenate(ys), "split": np.concatenate(splits),
            "height": np.concatenate(hs), "names": names}


DELTA_SCALE = 0.1
"""The refining head's raw outputs are box deltas / DELTA_SCALE (Fast R-CNN's normalisation);
the exported ``deltas`` output is in box widths and heights."""
FG_IOU, BG_IOU, REG_IOU = 0.5, 0.3, 0.4
"""A proposal is its best truth box's class at IoU ≥ FG_IOU, background below BG_IOU, neither
(no class loss) between; its box is regressed to the truth box at IoU ≥ REG_IOU."""


def proposal_samples(gt: np.ndarray, gt_cls: np.ndarray, props: np.ndarray,
                     scores: np.ndarray, background: int, rng: np.random.Generator,
                     per_truth: int = 3, jitter: float = 0.08) -> tuple:
    """One frame's training boxes for the refining stage: every truth box, one jittered copy
    of each (every side moved by a normal draw of ``jitter`` × the box's size), up to
    ``per_truth`` of the detector's proposals per truth box they match, and the detector's
    highest-scoring background proposals (max(6, 2 × truth boxes)). Returns (boxes (K, 4),
    class (K,): the truth class, ``background`` or -1 (neither), deltas (K, 4): the truth
    box's sides minus the box's, in box widths / heights, reg (K,) bool)."""
    from dashtraj.perception.detect import box_iou

    gt = np.asarray(gt, np.float64).reshape(-1, 4)
    props = np.asarray(props, np.float64).reshape(-1, 4)
    wh = np.concatenate([gt[:, 2:] - gt[:, :2]] * 2, 1)
    jit = gt + rng.normal(0.0, jitter, gt.shape) * wh
    jit[:, 2:] = np.maximum(jit[:, 2:], jit[:, :2] + 2)
    boxes = [gt, jit]
    if len(props):
        if len(gt):
            iou = box_iou(props, gt)
            best = iou.max(1)
            bg = np.flatnonzero(best < BG_IOU)
            fg = [rng.permutation(np.flatnonzero((iou.argmax(1) == j) & (best >= REG_IOU)))
                  [:per_truth] for j in range(len(gt))]
            fg = np.concatenate(fg) if fg else np.zeros(0, np.int64)
        else:
            bg, fg = np.arange(len(props)), np.zeros(0, np.int64)
        bg = bg[np.argsort(-scores[bg], kind="stable")][:max(6, 2 * len(gt))]
        boxes.append(props[np.sort(np.concatenate([fg, bg]).astype(np.int64))])
    boxes = np.concatenate(boxes)
    cls = np.full(len(boxes), background, np.int64)
    deltas = np.zeros((len(boxes), 4), np.float32)
    reg = np.zeros(len(boxes), bool)
    if len(gt):
        iou = box_iou(boxes, gt)
        j, best = iou.argmax(1), iou.max(1)
        cls = np.where(best >= FG_IOU, np.asarray(gt_cls)[j], np.where(best < BG_IOU,
                                                                        background, -1))
        reg = best >= REG_IOU
        bwh = np.concatenate([boxes[:, 2:] - boxes[:, :2]] * 2, 1)
        deltas = ((gt[j] - boxes) / np.maximum(bwh, 1e-6)).astype(np.float32)
        deltas[~reg] = 0
    return boxes, cls.astype(np.int64), deltas, reg


def extract_proposals(data, detector, crop_px: int = CROP_PX, margin: float = MARGIN,
                      seed: int = 0, conf: float = 0.01, log=None) -> dict:
    """`extract_crops` for the refining stage: the crops of `proposal_samples` over every
    image of a YOLO set, the proposals from ``detector`` (a `YoloDetector` or its ONNX
    path) at ``conf``. Adds "deltas" (N, 4) and "reg" (N,) to `extract_crops`' keys; "y"
    holds len(names) for background and -1 for neither."""
    from dashtraj.perception.detect import YoloDetector, box_crops, read_names_yaml

    root = Path(data)
    names = read_names_yaml(root / "data.yaml")
    det = detector if isinstance(detector, YoloDetector) else YoloDetector(detector, conf=conf)
    out: dict[str, list] = {k: [] for k in ("x", "y", "split", "height", "deltas", "reg")}
    total = {sp: len(list((root / "labels" / sp).glob("*.txt"))) for sp in ("train", "val")}
    for k, n, split, img, gt_cls, gt, _ in _labelled_images(root):
        d = det.detect([img])[0]
        boxes, cls, deltas, reg = proposal_samples(gt, gt_cls, d.boxes, d.scores, len(names),
                                                   np.random.default_rng([seed, k, n]))
        out["x"].append(box_crops(img, boxes, margin, crop_px, crop_px))
        out["y"].append(cls)
        out["split"].append(np.full(len(boxes), k, np.int64))
        out["height"].append(boxes[:, 3] - boxes[:, 1])
        out["deltas"].append(deltas)
        out["reg"].append(reg)
        if log is not None and (n + 1) % 500 == 0:
            log(f"proposals: {split} {n + 1}/{total[split]} images")
    if not out["x"]:
        raise ValueError(f"{root}: no images in labels/train or labels/val")
    res = {key: np.concatenate(v) for key, v in out.items()}
    res["names"] = names
    return res


def build_net(num_classes: int, pretrained: bool = True, blocks: int = BLOCKS,
              refine: bool = False):
    """The classifier network: the Lite0 stem and its first ``blocks`` blocks (of 16),
    global average pooling, dropout 0.2, one linear layer; with ``refine`` a second linear
    layer gives four box deltas (× DELTA_SCALE in eval mode: box widths / heights)."""
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
            ch = self.trunk._blocks[-1]._project_conv.out_channels
            self.fc = nn.Linear(ch, num_classes)
            self.box = nn.Linear(ch, 4) if refine else None

        def forward(self, x):
            t = self.trunk
            x = F.relu6(t._bn0(t._conv_stem(x)))
            for b in t._blocks:
                x = b(x)
            f = x.mean((2, 3))
            logits = self.fc(self.drop(f))
            if self.box is None:
                return logits
            u = self.box(f)
            return logits, (u if self.training else u * DELTA_SCALE)

    return BoxClassifierNet()


def _view_deltas(d: np.ndarray, ox: int, oy: int, c: int, s: int, input_px: int,
                 margin: float = MARGIN) -> np.ndarray:
    """A box's deltas to its truth box (box widths / heights) restated for a training view:
    the square of ``c`` crop pixels at (ox, oy) of its ``s`` px crop, shown at input_px,
    is the run-time centre view of another box (the view's own box); the deltas are
    returned relative to that box."""
    k = (1 + 2 * margin) / s
    o = (s - input_px) // 2
    scale = c / input_px
    out = np.empty(4, np.float32)
    for a, off in ((0, ox), (1, oy)):
        lo = off * k - margin - (o * k - margin) * scale
        out[a] = (d[a] - lo) / scale
        out[a + 2] = (1 + d[a + 2] - (lo + scale)) / scale
    return out


def _batch(x: np.ndarray, input_px: int, rng: np.random.Generator | None,
           deltas: np.ndarray | None = None, heights: np.ndarray | None = None,
           lowres: float = 0.0):
    """uint8 crops → normalised (B, 3, input_px, input_px) float tensor: the centre, or
    with ``rng`` a random square of input_px-6 .. crop px at a random place (rescaled),
    flipped half the time, brightness × 0.7-1.3 and ± 0.05. With ``deltas`` (B, 4) also
    returns them restated for each view (`_view_deltas`; a flip swaps and negates x).
    With ``lowres`` and the boxes' ``heights`` (frame pixels), that share of the views is
    shown as a frame of 1/1.5 to 1/3 the resolution would have drawn it (the view shrunk
    to the pixels the box would cover there, antialiased, and grown back)."""
    import torch
    import torch.nn.functional as F

    t = torch.from_numpy(np.ascontiguousarray(x)).permute(0, 3, 1, 2).float() / 255.0
    n, _, s, _ = t.shape
    dv = None if deltas is None else np.array(deltas, np.float32).reshape(n, 4)
    if rng is None:
        o = (s - input_px) // 2
        t = t[:, :, o:o + input_px, o:o + input_px]
    else:
        out = torch.empty(n, 3, input_px, input_px)
        for i in range(n):
            c = int(rng.integers(input_px - 6, s + 1))
            ox, oy = int(rng.integers(0, s - c + 1)), int(rng.integers(0, s - c + 1))
            patch = t[i:i + 1, :, oy:oy + c, ox:ox + c]
            if heights is not None and lowres > 0 and rng.random() < lowres:
                src = (1 + 2 * MARGIN) * float(heights[i]) * c / s / rng.uniform(1.5, 3.0)
                if src < c:
                    r = max(4, round(src))
                    patch = F.interpolate(patch, size=(r, r), mode="bilinear",
                                          align_corners=False, antialias=True)
            if dv is not None:
                dv[i] = _view_deltas(dv[i], ox, oy, c, s, input_px)
            if rng.random() < 0.5:
                patch = patch.flip(3)
                if dv is not None:
                    dv[i, 0], dv[i, 2] = -dv[i, 2], -dv[i, 0]
            out[i] = F.interpolate(patch, size=(input_px, input_px), mode="bilinear",
                                   align_corners=False)[0]
        gain = torch.from_numpy(rng.uniform(0.7, 1.3, (n, 1, 1, 1))).float()
        bias = torch.from_numpy(rng.uniform(-0.05, 0.05, (n, 1, 1, 1))).float()
        t = (out * gain + bias).clamp(0, 1)
    mean = torch.tensor(MEAN).view(1, 3, 1, 1)
    std = torch.tensor(STD).view(1, 3, 1, 1)
    if dv is not None:
        return (t - mean) / std, dv
    return (t - mean) / std


def _rel_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise IoU of boxes given as deltas to the unit box (0, 0, 1, 1)
    (`dashtraj.train.detector_train.box_iou_pairs`)."""
    import torch

    from dashtraj.train.detector_train import box_iou_pairs

    unit = np.array([0.0, 0.0, 1.0, 1.0])
    return box_iou_pairs(torch.from_numpy(unit + a), torch.from_numpy(unit + b)).numpy()


def evaluate(net, x: np.ndarray, y: np.ndarray, input_px: int = INPUT_PX,
             deltas: np.ndarray | None = None, reg: np.ndarray | None = None) -> dict:
    """Accuracy of the 15 classes, of the vehicle class alone (class // 3) and of the
    orientation alone (class % 3) on centre crops of the boxes of a vehicle class. A
    refining network adds: the background boxes it calls background (``bg_recall``), the
    vehicles it calls background (``fg_as_bg``), and the mean IoU of the regressed boxes
    with their truth boxes before and after its deltas (``iou_before``, ``iou_after``)."""
    import torch

    net.eval()
    pred, dpred = [], []
    with torch.no_grad():
        for i in range(0, len(x), 256):
            o = net(_batch(x[i:i + 256], input_px, None))
            if isinstance(o, tuple):
                dpred.append(o[1].numpy())
                o = o[0]
            pred.append(o.argmax(1).numpy())
    p = np.concatenate(pred) if pred else np.zeros(0, np.int64)
    nc = getattr(net.fc, "out_features", 0) - (1 if dpred else 0)
    fg = (y >= 0) & (y < nc) if dpred else np.ones(len(y), bool)
    p_fg, y_fg = p[fg], y[fg]
    n = max(len(y_fg), 1)
    res = {"acc": float((p_fg == y_fg).sum() / n),
           "vehicle_acc": float((p_fg // 3 == y_fg // 3).sum() / n),
           "orientation_acc": float((p_fg % 3 == y_fg % 3).sum() / n), "n": len(y_fg)}
    if dpred:
        bg = y == nc
        res["bg_recall"] = float((p[bg] == nc).mean()) if bg.any() else None
        res["fg_as_bg"] = float((p_fg == nc).mean()) if len(p_fg) else None
        res["n_bg"] = int(bg.sum())
        if deltas is not None and reg is not None and reg.any():
            d = np.concatenate(dpred)
            res["iou_before"] = float(_rel_iou(np.zeros_like(deltas[reg]), deltas[reg]).mean())
            res["iou_after"] = float(_rel_iou(d[reg], deltas[reg]).mean())
    return res


def train(data, out, epochs: int = 8, seed: int = 0, threads: int = 2, lr: float = 1e-3,
          batch: int = 64, input_px: int = INPUT_PX, blocks: int = BLOCKS, detector=None,
          lowres: float = 0.0, log=print) -> dict:
    """Train on a YOLO set's boxes; writes OUT/last.pt after every epoch (a rerun resumes
    from it), OUT/log.jsonl (one line per epoch: loss, validation accuracies, wall time)
    and OUT/crops.npz (the extracted crops, reused by a resumed run). Returns the last
    epoch's line plus ``names``.

    With ``detector`` (a detector ONNX) the stage also learns to refine: it trains on
    `extract_proposals`' boxes (the truth boxes, jittered copies, the detector's own
    proposals on the set's images) with one more class, background, and a box head
    (smooth L1 on the deltas / DELTA_SCALE of the boxes at IoU ≥ REG_IOU). ``lowres``: the
    share of training views drawn at a lower resolution (`_batch`)."""
    import torch
    import torch.nn.functional as F

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(threads)
    refine = detector is not None
    keys = ("x", "y", "split", "height") + (("deltas", "reg") if refine else ())
    cache = out / "crops.npz"
    if cache.is_file():
        z = np.load(cache, allow_pickle=False)
        if refine != ("deltas" in z.files):
            from dashtraj.errors import DashtrajError

            raise DashtrajError(f"{cache}: made {'without' if refine else 'with'} a detector's "
                                "proposals; train into another folder")
        d = {k: z[k] for k in keys}
        d["names"] = json.loads(str(z["names"]))
    else:
        d = (extract_proposals(data, detector, seed=seed, log=log) if refine
             else extract_crops(data))
        tmp = out / "crops.tmp.npz"
        np.savez(tmp, **{k: d[k] for k in keys}, names=np.array(json.dumps(d["names"])))
        tmp.replace(cache)
    names = list(d["names"])
    tr, va = np.flatnonzero(d["split"] == 0), np.flatnonzero(d["split"] == 1)
    torch.manual_seed(seed)
    net = build_net(len(names) + refine, blocks=blocks,
                    refine=refine).to(memory_format=torch.channels_last)
    opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=5e-4)
    per_epoch = len(tr) // batch
    total = max(1, epochs * per_epoch)
    start, wall0 = 0, 0.0
    ckpt = out / "last.pt"
    if ckpt.is_file():
        state = torch.load(ckpt, map_location="cpu", weights_only=False)
        if (int(state.get("blocks", BLOCKS)), int(state["input_px"]),
                bool(state.get("refine", False))) != (blocks, input_px, refine):
            from dashtraj.errors import DashtrajError

            raise DashtrajError(f"{ckpt}: trained with {state.get('blocks', BLOCKS)} blocks at "
                                f"{state['input_px']} px"
                                f"{', refining' if state.get('refine') else ''}, not {blocks} "
                                f"at {input_px}{', refining' if refine else ''}; resume "
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
            y = torch.from_numpy(d["y"][idx])
            if refine:
                x, dv = _batch(d["x"][idx], input_px, rng, d["deltas"][idx],
                               d["height"][idx], lowres)
                logits, u = net(x.contiguous(memory_format=torch.channels_last))
                loss = F.cross_entropy(logits, y, label_smoothing=0.1, ignore_index=-1)
                r = torch.from_numpy(d["reg"][idx])
                if r.any():
                    loss = loss + F.smooth_l1_loss(u[r], torch.from_numpy(dv)[r] / DELTA_SCALE)
            else:
                x = _batch(d["x"][idx], input_px, rng, None, d["height"][idx],
                           lowres).contiguous(memory_format=torch.channels_last)
                loss = F.cross_entropy(net(x), y, label_smoothing=0.1)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(loss.item())
        line = {"epoch": ep + 1, "loss": float(np.mean(losses)) if losses else None,
                "val": evaluate(net, d["x"][va], d["y"][va], input_px,
                                *((d["deltas"][va], d["reg"][va]) if refine else ())),
                "wall_s": wall0 + time.time() - t0}
        log(json.dumps(line))
        with open(out / "log.jsonl", "a", encoding="utf-8") as fh:
            fh.write(json.dumps(line) + "\n")
        tmp = out / "last.tmp.pt"
        torch.save({"model": net.state_dict(), "optimizer": opt.state_dict(), "epoch": ep,
                    "wall_s": line["wall_s"], "names": names, "input_px": input_px,
                    "blocks": blocks, "refine": refine, "lowres": lowres,
                    "seed": seed, "threads": threads}, tmp)
        tmp.replace(ckpt)
    return {**line, "names": names}


def export_onnx(checkpoint, path, fp16_weights: bool = True) -> None:
    """Write a checkpoint's classifier as ONNX: input ``images`` (N, 3, S, S), output
    ``logits`` (N, C) (a refining stage: (N, C + 1), background last, and ``deltas``
    (N, 4), with metadata ``background`` "1"); metadata ``names`` (JSON list),
    ``crop_px``, ``input_px``, ``margin`` (what `dashtraj.perception.detect.BoxClassifier`
    reads)."""
    import warnings

    import onnx
    import torch

    from dashtraj.train.detector_model import finish_onnx

    state = torch.load(checkpoint, map_location="cpu", weights_only=False)
    names, s = state["names"], int(state["input_px"])
    refine = bool(state.get("refine", False))
    net = build_net(len(names) + refine, pretrained=False,
                    blocks=int(state.get("blocks", BLOCKS)), refine=refine)
    net.load_state_dict(state["model"])
    net.eval()
    outs = ["logits", "deltas"] if refine else ["logits"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.onnx.export(net, (torch.zeros(1, 3, s, s),), str(path), input_names=["images"],
                          output_names=outs, opset_version=17,
                          dynamic_axes={"images": {0: "batch"}, **{o: {0: "batch"} for o in outs}},
                          dynamo=False)
    m = onnx.load(str(path))
    info = {"names": json.dumps(names), "crop_px": str(CROP_PX), "input_px": str(s),
            "margin": str(MARGIN), "description": "dashtraj box classifier (detector stage 2)"}
    if refine:
        info["background"] = "1"
        info["description"] = ("dashtraj box classifier and refiner (detector stage 2): logits "
                               "of the names then background, deltas of the box's x0, y0, x1, "
                               "y1 in box widths / heights")
    finish_onnx(m, path, info, fp16_weights)
