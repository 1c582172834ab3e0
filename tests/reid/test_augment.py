"""The ReID training's augmentations: low resolution, truncation at a border, random
erasing (`Recipe.lowres`, `.truncate`, `.erasing`; numpy and Pillow, no torch)."""

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


def test_truncation_cuts_one_border_and_stretches_the_rest():
    from dashtraj.reid.train import RECIPES, augment

    r = replace(RECIPES["cpu"], flip=False, translate=0.0, truncate=1.0, truncate_max=0.5)
    h = w = 60
    ramp = np.arange(w, dtype=np.float64) * 4  # column j is 4j, row i is 4i
    imgs = np.zeros((100, h, w, 3), np.uint8)
    imgs[..., 0] = ramp[None, None, :]
    imgs[..., 1] = ramp[None, :, None]
    a = augment(imgs, r, np.random.default_rng(2))
    assert np.array_equal(a, augment(imgs, r, np.random.default_rng(2)))  # seeded
    sides = {"left": 0, "right": 0, "bottom": 0, "top": 0}
    for x in a.astype(np.int16):
        cols, rows = x[0, :, 0], x[:, 0, 1]
        if cols[0] >= 4 * 6 - 2:  # at least 10 % of the width gone on the left
            sides["left"] += 1
            assert cols[-1] >= 4 * (w - 1) - 2 and rows[0] <= 2 and rows[-1] >= 4 * (h - 1) - 2
        elif cols[-1] <= 4 * (w - 6) + 2:
            sides["right"] += 1
            assert cols[0] <= 2 and rows[0] <= 2
        elif rows[-1] <= 4 * (h - 6) + 2:
            sides["bottom"] += 1
            assert cols[0] <= 2 and cols[-1] >= 4 * (w - 1) - 2
        else:
            assert rows[0] >= 4 * 6 - 2, "no border cut"
            sides["top"] += 1
        # never more than truncate_max of a side: half the ramp's span is kept
        span = 4 * (w - 1) * 0.5 - 4
        assert cols[-1] - cols[0] >= span and rows[-1] - rows[0] >= span
    assert sides["left"] > 20 and sides["right"] > 20 and sides["bottom"] + sides["top"] > 5
    # off: nothing drawn, nothing changed
    r0 = replace(r, truncate=0.0)
    g = np.random.default_rng(7)
    assert np.array_equal(augment(imgs, r0, g), imgs)
    assert g.random() == np.random.default_rng(7).random()


def test_random_erasing_paints_one_rectangle_the_mean_colour():
    from dashtraj.reid.preprocess import IMAGENET_MEAN
    from dashtraj.reid.train import RECIPES, augment

    fill = np.round(np.asarray(IMAGENET_MEAN) * 255).astype(np.uint8)
    r = replace(RECIPES["cpu"], flip=False, translate=0.0, erasing=0.5)
    rng = np.random.default_rng(0)
    imgs = rng.integers(0, 256, (200, 50, 40, 3)).astype(np.uint8)
    imgs[np.all(imgs == fill, axis=-1)] = 0  # the fill colour appears only where painted
    a = augment(imgs, r, np.random.default_rng(4))
    assert np.array_equal(a, augment(imgs, r, np.random.default_rng(4)))  # seeded
    painted = np.all(a == fill, axis=-1)
    hit = painted.any(axis=(1, 2))
    assert 70 <= hit.sum() <= 130  # about half
    assert np.array_equal(a[~hit], imgs[~hit])
    for m in painted[hit]:
        ys, xs = np.flatnonzero(m.any(1)), np.flatnonzero(m.any(0))
        box = m[ys[0]:ys[-1] + 1, xs[0]:xs[-1] + 1]
        assert box.all()  # one solid rectangle
        assert 0.02 * 0.8 <= box.size / m.size <= 0.4 * 1.25
