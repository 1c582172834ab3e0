"""Pictures for a person to check labels and crops (Pillow).

- ``draw_labels``: a frame with each vehicle's visible box drawn in its class colour
  and the text ``"<detection_class> <visible_fraction>"`` (e.g. ``car_front 0.93``);
  the silhouette box (where the vehicle would be without occluders) is drawn thin when
  it differs from the visible box.
- ``ContactSheet``: one row per vehicle, crops of it from several observers and times,
  so a person can see at a glance that a ReID identity always shows the same vehicle.
"""

from __future__ import annotations

import numpy as np

CLASS_COLORS: tuple[tuple[int, int, int], ...] = (
    (230, 25, 75), (245, 130, 48), (255, 225, 25),        # car front/back/side
    (60, 180, 75), (0, 130, 200), (70, 240, 240),         # truck
    (145, 30, 180), (240, 50, 230), (210, 245, 60),       # bus
    (250, 190, 212), (0, 128, 128), (220, 190, 255),      # motorcycle
    (170, 110, 40), (255, 250, 200), (128, 0, 0),         # bicycle
)  # fmt: skip
"""One RGB colour per ``DETECTION_CLASSES`` index."""


def _font(size: int = 11):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1
        return ImageFont.load_default()


def draw_labels(rgb: np.ndarray, labels, min_visible_pixels: int = 1):
    """A Pillow image of ``rgb`` (H, W, 3 uint8) with the labels' boxes and texts drawn.

    Args:
        labels: ``VehicleLabel`` objects (visible_box, silhouette_box in pixels,
            (x0, y0, x1, y1), exclusive ends).
        min_visible_pixels: labels with fewer visible pixels are not drawn.
    """
    from PIL import Image, ImageDraw

    img = Image.fromarray(np.ascontiguousarray(rgb))
    d = ImageDraw.Draw(img)
    font = _font(max(9, img.height // 40))
    for lab in labels:
        if lab.visible_box is None or lab.visible_pixels < min_visible_pixels:
            continue
        col = CLASS_COLORS[lab.detection_class_id % len(CLASS_COLORS)]
        x0, y0, x1, y1 = lab.visible_box
        if lab.silhouette_box is not None and tuple(lab.silhouette_box) != tuple(lab.visible_box):
            s0, t0, s1, t1 = lab.silhouette_box
            d.rectangle((s0, t0, s1 - 1, t1 - 1), outline=col, width=1)
        d.rectangle((x0, y0, x1 - 1, y1 - 1), outline=col, width=2)
        text = f"{lab.detection_class} {lab.visible_fraction:.2f}"
        tb = d.textbbox((x0, y0), text, font=font)
        ty = y0 - (tb[3] - tb[1]) - 2 if y0 - (tb[3] - tb[1]) - 2 >= 0 else y1
        tb = d.textbbox((x0, ty), text, font=font)
        d.rectangle(tb, fill=col)
        d.text((x0, ty), text, fill=(0, 0, 0), font=font)
    return img


class ContactSheet:
    """Crops per vehicle from several observers and times, laid out one row per vehicle.

    Args:
        per_row: crops per row. cell_px: thumbnail cell size, pixels.
        min_visible_fraction, min_box_height_px: crops below these are not collected.
        spacing_s: at most one crop per (vehicle, observer) every ``spacing_s`` seconds.
    """

    def __init__(self, per_row: int = 8, cell_px: int = 96, min_visible_fraction: float = 0.6,
                 min_box_height_px: int = 16, spacing_s: float = 2.0):
        self.per_row = int(per_row)
        self.cell_px = int(cell_px)
        self.min_visible_fraction = float(min_visible_fraction)
        self.min_box_height_px = int(min_box_height_px)
        self.spacing_s = float(spacing_s)
        self._crops: dict[int, list] = {}  # vehicle id -> [(observer, t, thumb)]
        self._titles: dict[int, str] = {}
        self._last: dict[tuple[int, int], float] = {}

    def add(self, key: int, title: str, source: int, t: float, crop) -> None:
        """Add a crop (Pillow image) of row ``key`` seen by ``source`` at time t (s)."""
        last = self._last.get((key, source))
        if last is not None and t - last < self.spacing_s:
            return
        self._last[(key, source)] = t
        thumb = crop.copy()
        thumb.thumbnail((self.cell_px, self.cell_px))
        self._crops.setdefault(key, []).append((source, t, thumb))
        self._titles[key] = title

    def add_frame(self, rf) -> None:
        """Add the well-visible vehicles of a ``RecordingFrame``."""
        from dashtraj.datasets.frames import crop_vehicle

        rgb = rf.frame_data.rgb
        for lab, vid, iid in zip(rf.frame_data.labels, rf.vehicle_ids, rf.identity_ids,
                                 strict=True):
            b = lab.visible_box
            if (b is None or lab.visible_fraction < self.min_visible_fraction
                    or b[3] - b[1] < self.min_box_height_px):
                continue
            self.add(int(vid), f"v{vid} id{iid} {lab.class_name}", rf.observer_id, rf.t,
                     crop_vehicle(rgb, b, margin=0.1))

    def render(self):
        """The sheet as a Pillow image (a placeholder text when no crop was collected)."""
        from PIL import Image, ImageDraw

        title_w, c = 130, self.cell_px
        keys = sorted(self._crops)
        img = Image.new("RGB", (title_w + c * self.per_row, max(1, len(keys)) * c), (32, 32, 32))
        d = ImageDraw.Draw(img)
        font = _font(11)
        if not keys:
            d.text((4, 4), "no crops (nothing well visible)", fill=(255, 255, 255), font=font)
            return img
        for r, key in enumerate(keys):
            y = r * c
            d.text((4, y + 4), self._titles[key], fill=(255, 255, 255), font=font)
            for j, (source, t, thumb) in enumerate(self._pick(self._crops[key])):
                x = title_w + j * c
                img.paste(thumb, (x + (c - thumb.width) // 2, y + (c - thumb.height) // 2))
                d.text((x + 2, y + c - 12), f"o{source} {t:.1f}s", fill=(255, 255, 0), font=font)
        return img

    def _pick(self, crops: list) -> list:
        """Up to ``per_row`` crops, round-robin over sources, each source in time order."""
        by_src: dict[int, list] = {}
        for item in sorted(crops, key=lambda c: (c[0], c[1])):
            by_src.setdefault(item[0], []).append(item)
        out, lists = [], [by_src[s] for s in sorted(by_src)]
        i = 0
        while len(out) < self.per_row and any(i < len(lst) for lst in lists):
            for lst in lists:
                if i < len(lst) and len(out) < self.per_row:
                    # spread picks over time: take every k-th of a long list
                    k = max(1, len(lst) // self.per_row)
                    if i * k < len(lst):
                        out.append(lst[i * k])
            i += 1
        return out
