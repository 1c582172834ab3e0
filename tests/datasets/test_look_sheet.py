"""The before/after look sheet of ``dashtraj render --preview [--compare DIR]``."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from dashtraj.datasets.frames import DatasetError, export_frames
from dashtraj.datasets.look_sheet import PANEL, nearest_reference, reference_images


def _refs(root):
    root.mkdir()
    sky_top = np.zeros((380, 640, 3), np.uint8)
    sky_top[:190] = (150, 180, 220)  # bright sky above a dark road
    sky_top[190:] = (60, 60, 60)
    Image.fromarray(sky_top).save(root / "a_sky_top.png")
    Image.fromarray(sky_top[::-1].copy()).save(root / "b_upside_down.jpg")
    (root / "notes.txt").write_text("not an image")
    return root


def test_nearest_reference_matches_the_layout(tmp_path):
    refs = reference_images(_refs(tmp_path / "refs"))
    assert [p.name for p in refs] == ["a_sky_top.png", "b_upside_down.jpg"]
    ours = np.zeros((360, 640, 3), np.uint8)
    ours[:200] = (120, 150, 200)
    ours[200:] = (80, 80, 80)
    cache: dict = {}
    assert nearest_reference(ours, refs, cache).name == "a_sky_top.png"
    assert nearest_reference(ours[::-1].copy(), refs, cache).name == "b_upside_down.jpg"
    with pytest.raises(DatasetError, match=r"no \.jpg/\.png images"):
        reference_images(tmp_path)


def test_preview_writes_the_look_sheet(gl_available, recordings, tmp_path):
    refs = _refs(tmp_path / "refs")
    s = export_frames(recordings[0], tmp_path / "out", every_s=1.0, preview=True,
                      compare_dir=refs)
    sheet = Image.open(s.preview_dir / "look_sheet.png")
    pw, ph = PANEL
    assert sheet.width == 4 * pw  # before, after, randomized, reference
    rows = (sheet.height - 22) // (ph + 22)
    assert rows == 3
    px = np.asarray(sheet.convert("RGB"), int)
    top = px[44:44 + ph]
    before, after, rand = (top[:, c * pw:(c + 1) * pw] for c in range(3))
    assert np.abs(before - after).mean() > 3 and np.abs(after - rand).mean() > 3
    s2 = export_frames(recordings[0], tmp_path / "out2", every_s=1.0, preview=True,
                       compare_dir=refs)
    assert (s2.preview_dir / "look_sheet.png").read_bytes() == \
        (s.preview_dir / "look_sheet.png").read_bytes()
