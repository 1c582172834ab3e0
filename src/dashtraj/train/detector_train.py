"""Training of the vehicle detector (torch; the ``.[train]`` extra only).

Recipes (``dashtraj.train.detector_recipes.RECIPES``, chosen by name):

- ``cpu``: what produced the shipped weights on a 2-core machine. The network sees
  random 320×192 crops of the 640×360 renders, rescaled by a random factor in
  [0.6, 1.25] (so a vehicle keeps the size it has at run time, when a 1280×720 frame
  is letterboxed to 640×384), centred on a labelled vehicle 4 times in 5: a quarter of
  the pixels of a whole frame per sample and more vehicles per pixel. The ImageNet
  backbone is frozen up to stride 16 (stem and blocks 0-10: their backward pass at high
  resolution is most of the cost on a CPU); its stride-32 blocks, the neck and the
  head train. AdamW, batch 8, lr 2e-3 with 100 warm-up steps then cosine
  to 2e-5 over three epochs (7 min on 2 free cores; hours when they are shared), weight
  EMA; channels-last.
- ``gpu``: whole 640×384 letterboxed frames at the cpu recipe's scale range, nothing
  frozen, batch 32, lr 1.5e-3 with 300 warm-up steps then cosine, 6 epochs; validated
  after the last epoch only. Load with ``workers`` processes: on an H200 with 14 of
  them a step took about 0.1 s (6,624 images: about 20 s an epoch), where scoring an
  early model on 300 validation images at conf 0.001 took minutes (its NMS visited
  thousands of candidates per image; it now stops at ``max_det`` kept boxes: 0.6 s →
  0.04 s an image).
- ``paper``: the paper's fine-tuning schedule where it applies (Sec. II-C1): whole
  frames letterboxed to 640, lr 1e-3 for the first epochs then 1e-4 for the last ten,
  nothing frozen; meant for a GPU.

Augmentation (both recipes): scale/translate (the crop above, or ±10 % scale jitter of
whole frames), brightness/contrast/saturation jitter. **No flips**: the paper uses
none ("such augmentation will produce images with incorrect labels"). A horizontal flip
would keep the 15 labels themselves (``side`` does not say left or right), but it
would turn right-hand traffic into left-hand traffic: oncoming (front) vehicles would
appear on the right of the road and vehicles seen from behind on the left, a pairing
of orientation and image position that never happens in the renders nor on the road.

Labels: the assignment is task-aligned (TAL, Feng et al. 2021, as in YOLOv8): per
ground-truth box the 10 cell centres inside it with the largest s^0.5 · IoU^6 are
positives; losses: varifocal BCE on IoU-aware soft class targets, GIoU on the boxes.

Determinism: every random draw comes from generators seeded by ``seed``; on a CPU
torch's kernels are deterministic for a fixed thread count, so the same seed and
thread count give the same weights, with any number of loading processes. On a GPU
cuDNN picks its kernels by timing them (``cudnn.benchmark``), and some are not
deterministic: two GPU runs differ in the last bits. A resumed run continues from the
state saved at the last checkpoint (model, EMA, optimizer, step, data order) and matches an
uninterrupted one except for float summation order in the first step after a resume.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import torch
from torch.nn import functional as F

from dashtraj.train.detector_recipes import Recipe, TrainError


# ----------------------------------------------------------------------------- data
def read_yolo_set(root: Path, split: str) -> list[tuple[Path, np.ndarray]]:
    """(image path, (K, 5) float [class, cx, cy, w, h] normalised) of one split."""
    img_dir = root / "images" / split
    if not img_dir.is_dir():
        raise TrainError(f"{root}: no images/{split}/ (expected a YOLO set made by "
                         "'dashtraj detection-dataset')")
    out = []
    for p in sorted(img_dir.glob("*.jpg")):
        lab = root / "labels" / split / (p.stem + ".txt")
        rows = []
        if lab.exists():
            for i, line in enumerate(lab.read_text(encoding="utf-8").splitlines(), 1):
                if line.strip():
                    vals = line.split()
                    if len(vals) != 5:
                        raise TrainError(f"{lab}:{i}: expected 'class cx cy w h'")
                    rows.append([float(v) for v in vals])
        out.append((p, np.array(rows, np.float32).reshape(-1, 5)))
    if not out:
        raise TrainError(f"{img_dir}: no .jpg images")
    return out


def load_image(path: Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB."""
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


def _resize(rgb: np.ndarray, w: int, h: int) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.fromarray(rgb).resize((w, h), Image.BILINEAR))


def augment(rgb: np.ndarray, labels: np.ndarray, recipe: Recipe,
            rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One training sample: (H, W, 3) uint8 and (K, 5) [class, x0, y0, x1, y1] pixels of it.

    Scale by a random factor, cut a crop (``recipe.crop``; centred on a random labelled
    box with probability ``focus_p``) or letterbox the whole frame to ``imgsz``; jitter
    brightness, contrast and saturation. No flips (module docstring).
    """
    h0, w0 = rgb.shape[:2]
    boxes = np.zeros((len(labels), 4), np.float32)
    if len(labels):
        cx, cy, bw, bh = (labels[:, 1] * w0, labels[:, 2] * h0, labels[:, 3] * w0,
                          labels[:, 4] * h0)
        boxes = np.stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], 1)
    out_h, out_w = recipe.crop if recipe.crop is not None else recipe.imgsz
    s = float(rng.uniform(*recipe.scale))
    if recipe.crop is None:
        s *= min(out_w / w0, out_h / h0)
    nw, nh = max(1, round(w0 * s)), max(1, round(h0 * s))
    img = _resize(rgb, nw, nh)
    boxes = boxes * np.array([nw / w0, nh / h0, nw / w0, nh / h0], np.float32)
    # top-left of the crop window in the rescaled image (may be negative: padding)
    if recipe.crop is not None and len(boxes) and rng.random() < recipe.focus_p:
        b = boxes[rng.integers(len(boxes))]
        cx = (b[0] + b[2]) / 2 + rng.uniform(-0.3, 0.3) * out_w
        cy = (b[1] + b[3]) / 2 + rng.uniform(-0.3, 0.3) * out_h
        x0, y0 = round(cx - out_w / 2), round(cy - out_h / 2)
    else:
        x0 = round(rng.uniform(min(0, nw - out_w), max(0, nw - out_w)))
        y0 = round(rng.uniform(min(0, nh - out_h), max(0, nh - out_h)))
    x0 = int(np.clip(x0, min(0, nw - out_w), max(0, nw - out_w)))
    y0 = int(np.clip(y0, min(0, nh - out_h), max(0, nh - out_h)))
    canvas = np.full((out_h, out_w, 3), 114, np.uint8)
    sx0, sy0 = max(0, x0), max(0, y0)
    sx1, sy1 = min(nw, x0 + out_w), min(nh, y0 + out_h)
    canvas[sy0 - y0:sy1 - y0, sx0 - x0:sx1 - x0] = img[sy0:sy1, sx0:sx1]
    cls = labels[:, 0] if len(labels) else np.zeros(0, np.float32)
    if len(boxes):
        area0 = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
        boxes = boxes - np.array([x0, y0, x0, y0], np.float32)
        clipped = boxes.copy()
        clipped[:, [0, 2]] = clipped[:, [0, 2]].clip(0, out_w)
        clipped[:, [1, 3]] = clipped[:, [1, 3]].clip(0, out_h)
        # ... and the valid image region (padding is not vehicle)
        area = (clipped[:, 2] - clipped[:, 0]) * (clipped[:, 3] - clipped[:, 1])
        keep = ((clipped[:, 3] - clipped[:, 1]) >= recipe.min_box_px) \
            & ((clipped[:, 2] - clipped[:, 0]) >= 2) & (area >= 0.4 * np.maximum(area0, 1e-6))
        boxes, cls = clipped[keep], cls[keep]
    # photometric jitter
    f = canvas.astype(np.float32)
    gain = rng.uniform(0.7, 1.3)
    contrast = rng.uniform(0.75, 1.25)
    sat = rng.uniform(0.6, 1.4)
    mean = f.mean()
    f = (f - mean) * contrast + mean * gain
    grey = f.mean(2, keepdims=True)
    f = grey + (f - grey) * sat
    canvas = f.clip(0, 255).astype(np.uint8)
    return canvas, np.concatenate([cls[:, None], boxes], 1).astype(np.float32)


def collate(samples) -> tuple[torch.Tensor, torch.Tensor]:
    """Images (B, 3, H, W) float [0, 1] channels-last; targets (B, M, 5) padded with
    class −1 (class, x0, y0, x1, y1 pixels)."""
    imgs = torch.from_numpy(np.stack([s[0] for s in samples])).permute(0, 3, 1, 2)
    imgs = imgs.float().div(255).contiguous(memory_format=torch.channels_last)
    m = max(1, max(len(s[1]) for s in samples))
    t = torch.full((len(samples), m, 5), -1.0)
    for i, s in enumerate(samples):
        if len(s[1]):
            t[i, :len(s[1])] = torch.from_numpy(s[1])
    return imgs, t


# ----------------------------------------------------------------------------- loss
def box_iou_pairs(a: torch.Tensor, b: torch.Tensor, giou: bool = False) -> torch.Tensor:
    """IoU (or GIoU) of boxes a[..., 4] and b[..., 4] (x0, y0, x1, y1), broadcast."""
    iw = (torch.minimum(a[..., 2], b[..., 2]) - torch.maximum(a[..., 0], b[..., 0])).clamp(0)
    ih = (torch.minimum(a[..., 3], b[..., 3]) - torch.maximum(a[..., 1], b[..., 1])).clamp(0)
    inter = iw * ih
    area_a = (a[..., 2] - a[..., 0]).clamp(0) * (a[..., 3] - a[..., 1]).clamp(0)
    area_b = (b[..., 2] - b[..., 0]).clamp(0) * (b[..., 3] - b[..., 1]).clamp(0)
    union = area_a + area_b - inter + 1e-9
    iou = inter / union
    if not giou:
        return iou
    cw = torch.maximum(a[..., 2], b[..., 2]) - torch.minimum(a[..., 0], b[..., 0])
    ch = torch.maximum(a[..., 3], b[..., 3]) - torch.minimum(a[..., 1], b[..., 1])
    c = cw * ch + 1e-9
    return iou - (c - union) / c


@torch.no_grad()
def assign(pred_boxes, pred_scores, anchors, targets, topk: int = 10, alpha: float = 0.5,
           beta: float = 6.0):
    """Task-aligned assignment (TAL).

    Args:
        pred_boxes: (B, N, 4) pixels; pred_scores: (B, N, C) probabilities;
        anchors: (N, 2) cell centres, pixels; targets: (B, M, 5) class (−1 = pad), box.

    Returns:
        target_boxes (B, N, 4), target_scores (B, N, C) soft (IoU-aware), fg (B, N) bool.
    """
    b, n, c = pred_scores.shape
    m = targets.shape[1]
    cls = targets[..., 0].long()
    valid = cls >= 0
    gt = targets[..., 1:]
    ax, ay = anchors[:, 0], anchors[:, 1]
    inside = ((ax[None, None] > gt[..., 0:1]) & (ax[None, None] < gt[..., 2:3])
              & (ay[None, None] > gt[..., 1:2]) & (ay[None, None] < gt[..., 3:4]))
    inside &= valid[..., None]
    iou = box_iou_pairs(gt[:, :, None, :], pred_boxes[:, None, :, :]).clamp(0)  # (B, M, N)
    score = torch.gather(pred_scores.transpose(1, 2), 1,
                         cls.clamp(min=0)[..., None].expand(b, m, n))  # (B, M, N)
    align = score.pow(alpha) * iou.pow(beta) * inside
    k = min(topk, n)
    top = align.topk(k, dim=-1).indices
    is_top = torch.zeros_like(inside)
    is_top.scatter_(-1, top, True)
    pos = is_top & inside
    # a small box may contain no cell centre: give it its nearest centre
    empty = valid & ~pos.any(-1)
    if empty.any():
        cxy = (gt[..., :2] + gt[..., 2:]) / 2
        d = ((cxy[:, :, None, :] - anchors[None, None]) ** 2).sum(-1)
        near = d.argmin(-1)
        extra = torch.zeros_like(pos)
        extra.scatter_(-1, near[..., None], True)
        pos |= extra & empty[..., None]
    # one ground truth per cell: the one with the largest IoU
    multi = pos.sum(1) > 1  # (B, N)
    if multi.any():
        best = (iou * pos).argmax(1)  # (B, N)
        one = F.one_hot(best, m).transpose(1, 2).bool()
        pos = torch.where(multi[:, None, :], one & pos, pos)
    fg = pos.any(1)
    gt_idx = pos.float().argmax(1)  # (B, N)
    tb = torch.gather(gt, 1, gt_idx[..., None].expand(b, n, 4))
    tc = torch.gather(cls.clamp(min=0), 1, gt_idx)
    align = align * pos
    max_align = align.amax(-1, keepdim=True)
    max_iou = (iou * pos).amax(-1, keepdim=True)
    norm = (align * max_iou / (max_align + 1e-9)).amax(1)  # (B, N)
    norm = torch.where(fg & (norm <= 0), torch.full_like(norm, 0.05), norm)
    ts = F.one_hot(tc, c).float() * (norm * fg)[..., None]
    return tb, ts, fg


def detection_loss(pred_boxes, logits, anchors, targets, box_gain: float = 5.0,
                   vfl_alpha: float = 0.75, vfl_gamma: float = 2.0):
    """(total loss, dict of parts): varifocal BCE on the IoU-aware class targets + GIoU,
    both normalised by the sum of the target scores (as YOLOv8)."""
    scores = logits.detach().sigmoid()
    tb, ts, fg = assign(pred_boxes.detach(), scores, anchors, targets)
    norm = ts.sum().clamp(min=1.0)
    # varifocal loss (Zhang et al. 2021): a positive entry is weighted by its IoU-aware
    # target q, a negative one by alpha * p^gamma, so the ~10^5 easy negatives of a batch
    # stop drowning the few positives (plain BCE kept every score near 0 for the first
    # hundreds of steps: too slow for a CPU budget)
    pos = (ts > 0).float()
    weight = (vfl_alpha * scores.pow(vfl_gamma) * (1 - pos) + ts * pos).detach()
    bce = F.binary_cross_entropy_with_logits(logits, ts, reduction="none")
    l_cls = (bce * weight).sum() / norm
    if fg.any():
        w = ts.sum(-1)[fg]
        giou = box_iou_pairs(pred_boxes[fg], tb[fg], giou=True)
        l_box = ((1.0 - giou) * w).sum() / norm
    else:
        l_box = pred_boxes.sum() * 0.0
    total = l_cls + box_gain * l_box
    return total, {"cls": float(l_cls.detach()), "box": float(l_box.detach())}


# ----------------------------------------------------------------------------- loop
class ModelEMA:
    """Exponential moving average of the weights, decay ramped as d·(1 − e^(−step/500))."""

    def __init__(self, model, decay: float):
        import copy

        self.ema = copy.deepcopy(model).eval()
        for p in self.ema.parameters():
            p.requires_grad_(False)
        self.decay = decay
        self.updates = 0

    @torch.no_grad()
    def update(self, model) -> None:
        self.updates += 1
        d = self.decay * (1 - math.exp(-self.updates / 500))
        msd = model.state_dict()
        for k, v in self.ema.state_dict().items():
            if v.dtype.is_floating_point:
                v.mul_(d).add_(msd[k].detach(), alpha=1 - d)
            else:
                v.copy_(msd[k])


def lr_at(recipe: Recipe, step: int, total: int, steps_per_epoch: int) -> float:
    """Learning rate of a step (warm-up, then cosine or step schedule)."""
    if step < recipe.warmup:
        return recipe.lr * (step + 1) / recipe.warmup
    if recipe.schedule == "step":
        switch = max(0, recipe.epochs - recipe.step_last) * steps_per_epoch
        return recipe.lr if step < switch else recipe.lr_final
    t = (step - recipe.warmup) / max(1, total - recipe.warmup)
    return recipe.lr_final + 0.5 * (recipe.lr - recipe.lr_final) * (1 + math.cos(math.pi * t))


def _freeze(model, n_blocks: int) -> list[torch.nn.Module]:
    """Freeze the stem and the first n_blocks backbone blocks; returns the frozen modules."""
    if n_blocks <= 0:
        return []
    bb = model.backbone
    frozen = [bb._conv_stem, bb._bn0, *bb._blocks[:n_blocks]]
    for mod in frozen:
        for p in mod.parameters():
            p.requires_grad_(False)
    return frozen


@torch.no_grad()
def predict_batch(model, imgs: torch.Tensor, conf: float = 0.001, iou: float = 0.6,
                  max_det: int = 300) -> list[np.ndarray]:
    """(K, 6) [x0, y0, x1, y1, score, class] per image, input pixels (numpy NMS of the
    run time, so training validation scores what the shipped model will do)."""
    from dashtraj.perception.detect import postprocess

    boxes, logits, _, _ = model(imgs.to(next(model.parameters()).device))
    xy = (boxes[..., :2] + boxes[..., 2:]) / 2
    wh = boxes[..., 2:] - boxes[..., :2]
    raw = torch.cat([xy, wh, logits.sigmoid()], -1).transpose(1, 2).float().cpu().numpy()
    return postprocess(raw, conf=conf, iou=iou, max_det=max_det)


def evaluate_split(model, items, recipe: Recipe, names) -> dict:
    """mAP of ``model`` on (image, labels) items letterboxed to ``recipe.imgsz``."""
    from dashtraj.perception.detect import letterbox
    from dashtraj.perception.detmetrics import evaluate_detections

    model.eval()
    preds, gts = [], []
    h, w = recipe.imgsz
    for i in range(0, len(items), 8):
        chunk = items[i:i + 8]
        arrs, lbs = [], []
        for p, lab in chunk:
            rgb = load_image(p)
            img, lb = letterbox(rgb, (h, w))
            arrs.append(img)
            lbs.append((rgb.shape, lb, lab))
        x = torch.from_numpy(np.stack(arrs)).permute(0, 3, 1, 2).float().div(255)
        x = x.contiguous(memory_format=torch.channels_last)
        for det, (shape, lb, lab) in zip(predict_batch(model, x), lbs, strict=True):
            preds.append(lb.boxes_to_image(det))
            h0, w0 = shape[:2]
            g = np.zeros((len(lab), 5), np.float32)
            if len(lab):
                cx, cy, bw, bh = lab[:, 1] * w0, lab[:, 2] * h0, lab[:, 3] * w0, lab[:, 4] * h0
                g = np.stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2, lab[:, 0]], 1)
            gts.append(g)
    return evaluate_detections(preds, gts, len(names), names=names)


class _StepBatches(torch.utils.data.Dataset):
    """The collated batches of one epoch's steps ``first``.. (item i = step first + i):
    image j of epoch ep is augmented with ``default_rng([seed, ep, j])``, whichever
    process loads it."""

    def __init__(self, items, order, recipe: Recipe, seed: int, epoch: int, first: int,
                 steps: int):
        self.items, self.order, self.recipe = items, order, recipe
        self.seed, self.epoch, self.first, self.steps = seed, epoch, first, steps

    def __len__(self) -> int:
        return max(0, self.steps - self.first)

    def __getitem__(self, i: int):
        si = self.first + i
        samples = []
        for j in self.order[si * self.recipe.batch:(si + 1) * self.recipe.batch]:
            p, lab = self.items[int(j)]
            r = np.random.default_rng(np.random.SeedSequence([self.seed, self.epoch, int(j)]))
            samples.append(augment(load_image(p), lab, self.recipe, r))
        return collate(samples)


def _rng_for(seed: int, epoch: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, epoch]))


def train(data_dir, out_dir, recipe: Recipe, seed: int = 0, epochs: int | None = None,
          max_images: int | None = None, stop_after: int | None = None, log=print,
          workers: int = 0) -> dict:
    """Train (or resume: ``out_dir/last.pt``) and write last.pt, best.pt, log.jsonl,
    recipe.json, curves.png in ``out_dir``.

    Args:
        data_dir: a YOLO set made by ``dashtraj detection-dataset``.
        recipe: a `Recipe`; ``epochs`` overrides its epoch count.
        max_images: use only the first N training (and validation) images (smoke tests).
        stop_after: stop once this many epochs are done, keeping the learning-rate
            schedule of the full ``epochs`` (a fixed-budget cut of a longer run, resumable
            to the end; two runs cut at the same epoch had the same steps and schedule).
        workers: data-loading processes (0: load and augment in this process). Each
            image's augmentation draws from its own generator, so the batches are the
            same for any count; on a GPU the loading is what limits the speed.

    Returns:
        a summary dict (epochs, steps, best map50 and map50_95, wall time, paths).
    """
    from dashtraj.reid.train import resolve_device  # auto: a GPU when torch sees one
    from dashtraj.train.detector_model import build_detector
    from dashtraj.world.camera import DETECTION_CLASSES

    data_dir, out = Path(data_dir), Path(out_dir)
    if epochs is not None:
        recipe = replace(recipe, epochs=epochs)
    names = list(DETECTION_CLASSES)
    train_items = read_yolo_set(data_dir, "train")[:max_images]
    val_items = read_yolo_set(data_dir, "val")
    if recipe.val_images:
        pick = _rng_for(seed, 10**6).permutation(len(val_items))[:recipe.val_images]
        val_items = [val_items[i] for i in sorted(pick)]
    val_items = val_items[:max_images]
    for p, lab in train_items + val_items:
        if len(lab) and (lab[:, 0].max() >= len(names) or lab[:, 0].min() < 0):
            raise TrainError(f"{p}: class id outside 0..{len(names) - 1}")
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(recipe.threads)
    torch.manual_seed(seed)
    # a GPU, where one is at hand, only makes it faster (same recipe, same data order)
    device = resolve_device()
    torch.backends.cudnn.benchmark = device.type == "cuda"  # one input size: tune once
    model = build_detector(len(names), pretrained=True).to(device,
                                                           memory_format=torch.channels_last)
    frozen = _freeze(model, recipe.freeze_blocks)
    decay, no_decay = [], []
    for p in model.parameters():
        if p.requires_grad:
            (decay if p.ndim == 4 else no_decay).append(p)
    opt = torch.optim.AdamW([{"params": decay, "weight_decay": recipe.weight_decay},
                             {"params": no_decay, "weight_decay": 0.0}], lr=recipe.lr)
    ema = ModelEMA(model, recipe.ema) if recipe.ema > 0 else None
    steps_per_epoch = max(1, len(train_items) // recipe.batch)
    total = steps_per_epoch * recipe.epochs
    state = {"epoch": 0, "step": 0, "best": -1.0, "wall_s": 0.0, "history": []}
    last = out / "last.pt"
    if last.exists():
        ck = torch.load(last, map_location=device, weights_only=False)
        model.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        if ema is not None:
            ema.ema.load_state_dict(ck["ema"])
            ema.updates = ck["ema_updates"]
        state = ck["state"]
        log(f"resumed from {last}: epoch {state['epoch']}, step {state['step']}")
    (out / "recipe.json").write_text(json.dumps({"recipe": asdict(recipe), "seed": seed,
                                                 "data": str(data_dir.resolve()),
                                                 "train_images": len(train_items),
                                                 "val_images": len(val_items)}, indent=1)
                                     + "\n", encoding="utf-8")

    def save(path: Path, extra: dict | None = None) -> None:
        ck = {"model": model.state_dict(), "optimizer": opt.state_dict(),
              "ema": ema.ema.state_dict() if ema else None,
              "ema_updates": ema.updates if ema else 0, "state": state,
              "recipe": asdict(recipe), "names": names, "seed": seed, **(extra or {})}
        tmp = path.with_suffix(".tmp")
        torch.save(ck, tmp)
        tmp.replace(path)

    t_start = time.time() - state["wall_s"]
    end = recipe.epochs if stop_after is None else min(recipe.epochs, stop_after)
    while state["epoch"] < end:
        ep = state["epoch"]
        rng = _rng_for(seed, ep)
        order = rng.permutation(len(train_items))
        # each image's augmentation draws from its own generator: resumable mid-epoch
        first = state["step"] - ep * steps_per_epoch
        model.train()
        for mod in frozen:
            mod.eval()
        t_ep = time.time()
        batches = _StepBatches(train_items, order, recipe, seed, ep, first, steps_per_epoch)
        loader = torch.utils.data.DataLoader(
            batches, batch_size=None, shuffle=False, num_workers=workers,
            pin_memory=device.type == "cuda", prefetch_factor=4 if workers else None)
        for si, (imgs, tgt) in enumerate(loader, first):
            imgs = imgs.to(device, non_blocking=True)
            tgt = tgt.to(device, non_blocking=True)
            lr = lr_at(recipe, state["step"], total, steps_per_epoch)
            for g in opt.param_groups:
                g["lr"] = lr
            boxes, logits, anchors, _ = model(imgs)
            loss, parts = detection_loss(boxes, logits, anchors, tgt)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 10.0)
            opt.step()
            if ema is not None:
                ema.update(model)
            state["step"] += 1
            state["wall_s"] = time.time() - t_start
            if state["step"] % 10 == 0:
                log(f"epoch {ep + 1}/{recipe.epochs} step {state['step']}/{total} "
                    f"loss {loss.item():.3f} (cls {parts['cls']:.3f} box {parts['box']:.3f}) "
                    f"lr {lr:.2e} {(time.time() - t_ep) / (si - first + 1):.1f} s/step")
                with open(out / "steps.jsonl", "a", encoding="utf-8") as fh:
                    fh.write(json.dumps({"step": state["step"], "epoch": ep, "lr": lr,
                                         "loss": loss.item(), **parts}) + "\n")
            if state["step"] % 50 == 0:
                save(last)
        state["epoch"] = ep + 1
        state["wall_s"] = time.time() - t_start
        if (ep + 1) % recipe.val_every and ep + 1 < end:
            save(last)
            log(f"epoch {ep + 1}: not validated (every {recipe.val_every} epochs)")
            continue
        eval_model = ema.ema if ema is not None else model
        res = evaluate_split(eval_model, val_items, recipe, names)
        state["wall_s"] = time.time() - t_start
        rec = {"epoch": ep + 1, "step": state["step"], "map50": res["map50"],
               "map50_95": res["map50_95"], "map50_24px": res["map50_24px"],
               "wall_s": round(state["wall_s"], 1)}
        state["history"].append(rec)
        with open(out / "log.jsonl", "a", encoding="utf-8") as fh:
            fh.write(json.dumps(rec) + "\n")
        log(f"epoch {ep + 1}: val mAP50 {res['map50']:.3f} mAP50-95 {res['map50_95']:.3f} "
            f"mAP50(>=24px) {res['map50_24px']:.3f}")
        if res["map50_95"] > state["best"]:
            state["best"] = res["map50_95"]
            save(out / "best.pt", {"val": res})
        save(last)
        write_curves(out)
    return {"epochs": state["epoch"], "steps": state["step"], "best_map50_95": state["best"],
            "history": state["history"], "wall_s": round(state["wall_s"], 1),
            "last": str(last), "best": str(out / "best.pt")}


def write_curves(run_dir) -> Path:
    """DIR/curves.png: training loss per step and validation mAP per epoch."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    run_dir = Path(run_dir)
    steps = [json.loads(x) for x in (run_dir / "steps.jsonl").read_text().splitlines()
             if x.strip()] if (run_dir / "steps.jsonl").exists() else []
    eps = [json.loads(x) for x in (run_dir / "log.jsonl").read_text().splitlines()
           if x.strip()] if (run_dir / "log.jsonl").exists() else []
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    if steps:
        a.plot([s["step"] for s in steps], [s["loss"] for s in steps], label="total")
        a.plot([s["step"] for s in steps], [s["cls"] for s in steps], label="cls (BCE)")
        a.plot([s["step"] for s in steps], [s["box"] for s in steps], label="box (1-GIoU)")
        a.set_xlabel("step")
        a.set_ylabel("loss")
        a.legend()
    if eps:
        for k, lab in (("map50", "mAP50"), ("map50_95", "mAP50-95"),
                       ("map50_24px", "mAP50, boxes >= 24 px")):
            b.plot([e["epoch"] for e in eps], [e[k] for e in eps], marker="o", label=lab)
        b.set_xlabel("epoch")
        b.set_ylim(0, 1)
        b.legend()
    b.set_title("validation (EMA weights)")
    fig.tight_layout()
    path = run_dir / "curves.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def export_checkpoint(ckpt_path, onnx_path, meta: dict | None = None) -> dict:
    """Export a checkpoint's EMA weights (or its model weights) to ONNX; returns the
    metadata written."""
    from dashtraj.train.detector_model import build_detector, export_onnx

    try:
        ck = torch.load(ckpt_path, map_location="cpu", weights_only=False)
    except Exception as e:  # a pickle or zip error of any kind: not a checkpoint
        raise TrainError(f"{ckpt_path}: not a torch checkpoint ({type(e).__name__}: {e})") from e
    missing = ([k for k in ("names", "model", "recipe", "seed", "state") if k not in ck]
               if isinstance(ck, dict) else ["names"])
    if missing:
        raise TrainError(f"{ckpt_path}: not a checkpoint of 'dashtraj detector train' (no "
                         f"{missing[0]!r} entry: give a run's best.pt or last.pt)")
    names = ck["names"]
    for k in ("model", "ema"):  # checkpoints written on a GPU
        if ck.get(k) is not None:
            ck[k] = {n: v.cpu() for n, v in ck[k].items()}
    model = build_detector(len(names), pretrained=False)
    model.load_state_dict(ck["ema"] if ck.get("ema") is not None else ck["model"])
    rec = ck["recipe"]
    imgsz = tuple(rec["imgsz"])
    info = {"recipe": rec["name"], "seed": ck["seed"], "epoch": ck["state"]["epoch"],
            "step": ck["state"]["step"], "wall_s": round(ck["state"]["wall_s"]),
            **(meta or {})}
    export_onnx(model, onnx_path, imgsz, names, info)
    return {"imgsz": list(imgsz), "names": names, **info}
