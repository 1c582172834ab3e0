"""The detector's training recipes, without torch: `dashtraj detector train` and the tests
read them here (a test checks that the `cpu` recipe is the one the shipped model's card records,
so that `make weights` reproduces the shipped model); `dashtraj.train.detector_train` runs them.
"""

from __future__ import annotations

from dataclasses import dataclass

from dashtraj.errors import DashtrajError


class TrainError(DashtrajError):
    """A training set or run directory that cannot be used."""


@dataclass(frozen=True)
class Recipe:
    """Training settings; written to ``DIR/recipe.json``.

    Attributes:
        name: recipe name. imgsz: (H, W) of the network input at run time, pixels.
        crop: (H, W) of the training crops, pixels, or None for whole letterboxed frames.
        scale: (lo, hi) random rescale factor of a training image.
        epochs: passes over the training images. batch: images per step.
        lr, lr_final: AdamW learning rate at the start (after warm-up) and the end.
        schedule: "cosine" or "step" (lr until ``epochs - step_last``, then lr_final).
        warmup: linear warm-up steps. weight_decay: AdamW decay of conv weights.
        freeze_blocks: backbone blocks (0..15, stem counted with block 0) kept frozen.
        ema: EMA decay (0 = off). focus_p: share of crops centred on a labelled vehicle.
        min_box_px: boxes smaller than this (height, after augmentation) are dropped.
        val_images: validation images scored after each epoch (0 = all).
        val_every: validate every this many epochs (and after the last one); best.pt
            is the best validated epoch.
        threads: torch threads.
    """

    name: str = "cpu"
    imgsz: tuple[int, int] = (384, 640)
    crop: tuple[int, int] | None = (192, 320)
    scale: tuple[float, float] = (0.6, 1.25)
    epochs: int = 20
    batch: int = 8
    lr: float = 2e-3
    lr_final: float = 2e-5
    schedule: str = "cosine"
    step_last: int = 10
    warmup: int = 100
    weight_decay: float = 5e-4
    freeze_blocks: int = 11
    ema: float = 0.999
    focus_p: float = 0.8
    min_box_px: float = 4.0
    val_images: int = 150
    threads: int = 2
    val_every: int = 1


RECIPES = {
    "cpu": Recipe(),
    # a GPU's: whole letterboxed frames (4x the pixels of a cpu crop) at the cpu recipe's
    # scale range, the whole backbone trained, batch 32 (load with --workers); validated
    # after the last epoch only (the one run of it had a budget of minutes)
    "gpu": Recipe(name="gpu", crop=None, epochs=6, batch=32, lr=1.5e-3, lr_final=1.5e-5,
                  warmup=300, freeze_blocks=0, val_images=200, threads=4, val_every=1000),
    "paper": Recipe(name="paper", crop=None, scale=(0.9, 1.1), epochs=110, batch=16,
                    lr=1e-3, lr_final=1e-4, schedule="step", step_last=10, warmup=500,
                    freeze_blocks=0, val_images=0),
}


def get_recipe(name: str) -> Recipe:
    """The recipe of this name; TrainError lists the valid ones."""
    if name not in RECIPES:
        raise TrainError(f"unknown recipe {name!r}; valid: {', '.join(RECIPES)}")
    return RECIPES[name]
