"""The ReID training's low-resolution augmentation (`Recipe.lowres`; numpy and Pillow,
no torch)."""

from dataclasses import replace

import numpy as np


def test_lowres_augmentation_shrinks_a_share_and_is_seeded():
    from dashtraj.reid.train import RECIPES, augment

    r0 = replace(RECIPES["cpu"], flip=False, translate=0.0)
    rng = np.random.default_rng(0)
    imgs = rng.integers(0, 256, (200, 64, 64, 3)).astype(np.uint8)  # all fine detail
    # off: the images pass untouched and no random number is drawn
    g = np.random.default_rng(7)
    assert np.array_equal(augment(imgs, r0, g), imgs)
    assert g.random() == np.random.default_rng(7).random()
    r = replace(r0, lowres=0.5, lowres_px=(12, 24))
    a = augment(imgs, r, np.random.default_rng(1))
    assert np.array_equal(a, augment(imgs, r, np.random.default_rng(1)))  # seeded
    assert a.shape == imgs.shape and a.dtype == np.uint8
    changed = np.any(a != imgs, axis=(1, 2, 3))
    assert 70 <= changed.sum() <= 130  # about half
    # a shrunk image lost its fine detail: neighbouring pixels differ far less
    def detail(x):
        return np.abs(np.diff(x.astype(np.int16), axis=2)).mean()
    assert max(detail(x) for x in a[changed]) < 0.5 * min(detail(x) for x in imgs[changed])
