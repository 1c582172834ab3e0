"""A contact sheet of our renders before and after the realistic look, beside real
frames of a similar street (``dashtraj render RUN --preview [--compare DIR]``).

Rows: the ``n`` sampled observer frames with the most visible vehicles (at most one per
observer while observers remain, then any). Columns: *before* (the ``flat`` look: the
renderer as it was before lighting, materials and camera effects), *after* (the
renderer's default look, clear daytime), *randomized* (a domain-randomized look,
``random_look(default_rng([seed, row]))``) and, with ``reference_dir``, the reference
frame whose coarse layout is nearest to the *after* frame: both images as 32 × 18
grey thumbnails (centre-cropped to 16:9), each standardised to zero mean and unit
variance, nearest in Euclidean distance. The reference frames are only looked at
(validation pictures), never used to choose or tune anything in the renderer.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dashtraj.datasets.frames import DatasetError, recording_frames

PANEL = (320, 180)
"""Size of one picture of the sheet, pixels (W, H)."""
REF_SUFFIXES = (".jpg", ".jpeg", ".png")


def _crop_16_9(img):
    w, h = img.size
    th = round(w * 9 / 16)
    if th <= h:
        top = (h - th) // 2
        return img.crop((0, top, w, top + th))
    tw = round(h * 16 / 9)
    left = (w - tw) // 2
    return img.crop((left, 0, left + tw, h))


def layout_descriptor(img) -> np.ndarray:
    """(576,) standardised 32 × 18 grey thumbnail of a Pillow image (16:9 centre crop)."""
    from PIL import Image

    g = np.asarray(_crop_16_9(img).convert("L").resize((32, 18), Image.Resampling.BOX), float)
    g = g.ravel()
    return (g - g.mean()) / (g.std() + 1e-6)


def reference_images(reference_dir) -> list[Path]:
    """Image files of a reference folder (its ``images/`` subfolder if it has one), sorted.
    Raises DatasetError naming the folder when it has none."""
    d = Path(reference_dir)
    if (d / "images").is_dir():
        d = d / "images"
    files = sorted(p for p in d.glob("*") if p.suffix.lower() in REF_SUFFIXES) if d.is_dir() \
        else []
    if not files:
        raise DatasetError(f"--compare {reference_dir}: no .jpg/.png images there")
    return files


def nearest_reference(rgb: np.ndarray, refs: list[Path], cache: dict) -> Path:
    """The reference file whose layout descriptor is nearest to that of ``rgb``."""
    from PIL import Image

    if "desc" not in cache:
        cache["desc"] = np.stack([layout_descriptor(Image.open(p)) for p in refs])
    d = ((cache["desc"] - layout_descriptor(Image.fromarray(rgb))) ** 2).sum(axis=1)
    return refs[int(np.argmin(d))]


def look_sheet(recording, out_png, every_s: float = 0.5, size=None, observers=None,
               reference_dir=None, n: int = 3, seed: int = 0) -> Path:
    """Write the contact sheet PNG (module docstring) and return its path.

    Args:
        recording: an opened ``Recording``. every_s, size, observers: as for
            ``recording_frames``. reference_dir: folder of reference frames (e.g. CARLA
            frames) or None. n: rows. seed: seed of the randomized column.
    """
    from PIL import Image, ImageDraw

    from dashtraj.datasets.frames import open_renderer
    from dashtraj.render.look import LookConfig, preset
    from dashtraj.render.randomize import frame_rng, random_look

    spec = recording.config.camera
    w, h = size if size is not None else (spec.width_px, spec.height_px)
    renderer = open_renderer(recording.map_path, w, h, spec.fov_deg, msaa=4)
    try:
        scored = []
        for rf in recording_frames(recording, every_s, (w, h), observers, renderer=renderer):
            n_vis = sum(1 for lb in rf.frame_data.labels if lb.visible_pixels >= 50)
            scored.append((-n_vis, rf.observer_id, rf.frame))
        if not scored:
            raise DatasetError(f"{recording.path}: no frame to preview")
        scored.sort()
        chosen, seen = [], set()
        for _, o, k in scored:  # one row per observer first, then the next best
            if o not in seen and len(chosen) < n:
                chosen.append((o, k))
                seen.add(o)
        for _, o, k in scored:
            if len(chosen) >= n:
                break
            if (o, k) not in chosen:
                chosen.append((o, k))
        rows = {key: {} for key in chosen}
        columns = [("before", lambda i: preset("flat")), ("after", lambda i: LookConfig()),
                   ("randomized", lambda i: random_look(frame_rng(seed, i)))]
        for name, look_of in columns:
            def look_for(o, k, look_of=look_of):
                key = (o, k)
                return look_of(chosen.index(key)) if key in rows else LookConfig()
            obs = sorted({o for o, _ in chosen})
            for rf in recording_frames(recording, every_s, (w, h), obs, renderer=renderer,
                                       look_for=look_for):
                if (rf.observer_id, rf.frame) in rows:
                    rows[(rf.observer_id, rf.frame)][name] = rf.frame_data.rgb
    finally:
        renderer.release()
    refs = reference_images(reference_dir) if reference_dir is not None else []
    cache: dict = {}
    pw, ph = PANEL
    head = 22
    ncol = len(columns) + (1 if refs else 0)
    sheet = Image.new("RGB", (ncol * pw, head + len(chosen) * (ph + head)), (24, 24, 24))
    draw = ImageDraw.Draw(sheet)
    titles = ["before: flat look", "after: default look (clear)", "after: randomized look"]
    if refs:
        titles.append("reference: nearest layout")
    for c, t in enumerate(titles):
        draw.text((c * pw + 6, 5), t, fill=(235, 235, 235))
    for r, key in enumerate(chosen):
        y = head + r * (ph + head)
        draw.text((6, y + 4), f"observer {key[0]}, frame {key[1]}", fill=(200, 200, 200))
        for c, (name, _) in enumerate(columns):
            img = Image.fromarray(rows[key][name]).resize(PANEL, Image.Resampling.LANCZOS)
            sheet.paste(img, (c * pw, y + head))
        if refs:
            ref = nearest_reference(rows[key]["after"], refs, cache)
            img = _crop_16_9(Image.open(ref).convert("RGB")).resize(PANEL,
                                                                    Image.Resampling.LANCZOS)
            sheet.paste(img, (len(columns) * pw, y + head))
            draw.text((len(columns) * pw + 6, y + 4), ref.name, fill=(200, 200, 200))
    out = Path(out_png)
    out.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(out, format="PNG", optimize=True)
    return out
