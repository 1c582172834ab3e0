"""A YOLO detection set (15 classes: class × orientation) rendered from recordings, or
read from drives with ground truth (`dashtraj.datasets.drive_truth`: CARLA's own frames
from ``carla-record``, their labels from the vehicles' boxes and the depth camera; the
images scaled to the set's size).

Layout (Ultralytics/YOLOv5-7 format)::

    out/images/train/*.jpg   out/labels/train/*.txt
    out/images/val/*.jpg     out/labels/val/*.txt
    out/data.yaml            (path, train, val, nc: 15, names: DETECTION_CLASSES in order)
    out/dataset.json         (the DetectionConfig, the split and the counts)

Image names: ``r<recording index:02d>_<recording dir name>_o<observer>_<frame:06d>.jpg``
(frame = state step index). One label line per kept vehicle:
``class_id cx cy w h`` — the *visible* box (``VehicleLabel.visible_box``: the tight
bound of the vehicle's unoccluded pixels), centre and size divided by the image width
and height, so all four numbers lie in [0, 1]. A frame with no kept vehicle gets an
empty .txt (a background image for YOLO).

Filters: a vehicle is labelled when its visible box is at least ``min_box_height_px``
pixels high and its occlusion ``1 − visible_fraction`` is at most ``max_occlusion``.
Vehicles that fail are simply left unlabelled, *while their pixels stay in the
image*: YOLO then treats a heavily occluded or tiny vehicle as background, which
teaches the detector to ignore such vehicles (and penalises it mildly when it finds
them). This follows the usual practice for tiny/occluded objects; a dataset that
wants "ignore" regions needs a format YOLO does not have.

Split: by recording, never frames of one recording on both sides (consecutive
frames are near-duplicates; mixing them would inflate validation scores). With one
recording the split is by observer instead (each observer's frames on one side) and
``dataset.json`` says so (``split_by``).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from dashtraj.datasets.frames import DatasetError, encode_jpeg, recording_frames, source_frames


@dataclass(frozen=True)
class DetectionConfig:
    """Settings of a detection set; written to ``dataset.json``.

    Attributes:
        every_s: sampling period, seconds. size: (W, H) pixels.
        min_box_height_px: smallest labelled visible-box height, pixels.
        max_occlusion: largest labelled 1 − visible_fraction.
        val_fraction: share of recordings (or observers, with one recording) in val.
        seed: seed of the split.
        randomize: draw a look per image (``dashtraj.render.randomize``: weather, sun,
            scene colours, textures, camera effects) from
            ``default_rng([randomize_seed, recording index, observer, frame])``; the
            drawn looks go to ``looks.parquet`` (one row per image).
        randomize_seed: seed of those draws.
    """

    every_s: float = 0.5
    size: tuple[int, int] = (640, 360)
    min_box_height_px: float = 10.0
    max_occlusion: float = 0.7
    val_fraction: float = 0.2
    seed: int = 0
    randomize: bool = False
    randomize_seed: int = 0


def yolo_lines(labels, width: int, height: int, min_box_height_px: float,
               max_occlusion: float) -> list[str]:
    """YOLO label lines ``"class_id cx cy w h"`` (normalised) of the kept labels.

    Args:
        labels: ``VehicleLabel`` objects of one frame (visible_box in pixels,
            (x0, y0, x1, y1), exclusive ends).
        width, height: image size, pixels.
    """
    out = []
    for lab in labels:
        b = lab.visible_box
        if b is None or b[3] - b[1] < min_box_height_px:
            continue
        if 1.0 - lab.visible_fraction > max_occlusion:
            continue
        x0, y0, x1, y1 = (float(v) for v in b)
        cx, cy = (x0 + x1) / 2 / width, (y0 + y1) / 2 / height
        w, h = (x1 - x0) / width, (y1 - y0) / height
        out.append(f"{int(lab.detection_class_id)} {cx:.6f} {cy:.6f} {w:.6f} {h:.6f}")
    return out


def split_units(n: int, val_fraction: float, rng: np.random.Generator) -> np.ndarray:
    """(n,) bool, True = val: round(n × val_fraction) units (at least 1 when n ≥ 2 and
    val_fraction > 0, at most n − 1), drawn with ``rng``."""
    n_val = round(n * val_fraction)
    if val_fraction > 0 and n >= 2:
        n_val = min(max(n_val, 1), n - 1)
    else:
        n_val = 0
    is_val = np.zeros(n, bool)
    is_val[rng.permutation(n)[:n_val]] = True
    return is_val


def data_yaml(out_dir: Path) -> str:
    """The text of ``data.yaml`` (written by hand: no YAML dependency)."""
    from dashtraj.world.camera import DETECTION_CLASSES

    names = "\n".join(f"  {i}: {n}" for i, n in enumerate(DETECTION_CLASSES))
    return (
        "# dashtraj detection set: 15 classes (vehicle class x orientation), visible boxes.\n"
        "# Vehicles under min_box_height_px or over max_occlusion are NOT labelled but stay\n"
        "# in the images (YOLO treats them as background); see dataset.json.\n"
        f"path: {out_dir.resolve().as_posix()}\n"
        "train: images/train\n"
        "val: images/val\n"
        f"nc: {len(DETECTION_CLASSES)}\n"
        f"names:\n{names}\n"
    )


def build_detection_dataset(recordings, out_dir, config: DetectionConfig = DetectionConfig(),
                            progress=None, workers: int = 1, train_only=()) -> dict:
    """Render recordings into a YOLO detection set (layout in the module docstring).

    Args:
        recordings: opened ``Recording`` objects, in a fixed order (indices in names).
        out_dir: output directory (created; existing files of the same names are
            overwritten).
        config: a ``DetectionConfig``.
        progress: called with no argument after each frame (each recording with
            ``workers`` > 1), or None.
        workers: processes rendering one recording each at a time (each its own GL
            context, started with ``spawn``); 1 renders in this process. The set's files
            are the same bytes for any count (every image depends only on its recording,
            observer and frame).
        train_only: more recordings, all in train, after ``recordings``: the split of
            ``recordings`` (and their images) stay what they are without them, so a set
            grows its training part and keeps its validation recordings.

    Returns:
        the ``dataset.json`` dict: config, split_by ("recording" | "observer"), the
        val recordings/observers, and images/labels/background counts per split.

    Raises:
        DatasetError: no recording given, or a recording without observers.
    """
    from dashtraj.datasets.drive import Drive
    from dashtraj.datasets.frames import observer_ids

    recs = list(recordings)
    extra = list(train_only)
    if not recs:
        raise DatasetError("no recording given")
    d = next((r for r in (*recs, *extra) if isinstance(r, Drive)), None)
    if config.randomize and d is not None:
        raise DatasetError(f"{d.path} is a drive: its images are what they are (no "
                           "randomized look)")
    out = Path(out_dir)
    for split in ("train", "val"):
        (out / "images" / split).mkdir(parents=True, exist_ok=True)
        (out / "labels" / split).mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(config.seed)
    if len(recs) > 1:
        split_by = "recording"
        rec_val = split_units(len(recs), config.val_fraction, rng)
        val_units = [str(recs[i].path) for i in np.flatnonzero(rec_val)]
        val_of = [bool(v) for v in rec_val]
    else:
        split_by = "observer"
        obs = observer_ids(recs[0])
        if not obs:
            raise DatasetError(f"{recs[0].path / 'vehicles.csv'}: no observer")
        obs_val = dict(zip(obs, split_units(len(obs), config.val_fraction, rng).tolist(),
                           strict=True))
        val_units = [o for o in obs if obs_val[o]]
        val_of = [obs_val]
    # appended after the split: it, and the others' indices (their looks), stay as they were
    val_of += [False] * len(extra)
    recs += extra
    jobs = [(ri, str(rec.path), val_of[ri], str(out), config) for ri, rec in enumerate(recs)]
    if workers <= 1 or len(recs) == 1:
        parts = [_render_recording(*job, rec=rec, progress=progress)
                 for job, rec in zip(jobs, recs, strict=True)]
    else:
        import multiprocessing as mp

        parts = []
        with mp.get_context("spawn").Pool(min(workers, len(recs))) as pool:
            for part in pool.imap(_render_job, jobs, chunksize=1):
                parts.append(part)
                if progress is not None:
                    progress()
    counts = {s: {"images": 0, "labels": 0, "background": 0} for s in ("train", "val")}
    class_counts = np.zeros(15, np.int64)
    look_rows: list[dict] = []
    for part in parts:
        for s in counts:
            for k in counts[s]:
                counts[s][k] += part["counts"][s][k]
        class_counts += part["class_counts"]
        look_rows.extend(part["looks"])
    (out / "data.yaml").write_text(data_yaml(out), encoding="utf-8")
    from dashtraj.world.camera import DETECTION_CLASSES

    info = {
        "format": "yolo", "config": {**asdict(config), "size": list(config.size)},
        "recordings": [str(r.path) for r in recs], "split_by": split_by, "val": val_units,
        "train_only": [str(r.path) for r in extra],
        "counts": counts,
        "class_counts": {n: int(c) for n, c in zip(DETECTION_CLASSES, class_counts, strict=True)},
        "note": ("vehicles failing min_box_height_px / max_occlusion are left unlabelled "
                 "in their images (YOLO sees them as background)"),
    }
    if config.randomize:
        info["randomize"] = _write_looks(out, look_rows, config.randomize_seed)
    if split_by == "observer" and len(val_units) == 0:
        info["warning"] = "one recording with one observer: no validation images"
    (out / "dataset.json").write_text(json.dumps(info, indent=1, sort_keys=True) + "\n",
                                      encoding="utf-8")
    return info


def open_recording_or_drive(path):
    """A recording, or a drive with truth (`dashtraj.datasets.drive.open_with_truth`):
    a drive without ``truth.csv`` has no labels to give (DatasetError)."""
    from dashtraj.datasets.drive import open_with_truth

    return open_with_truth(path, "no labels for a detection set", DatasetError)


def _render_job(job: tuple) -> dict:
    """A worker process's `_render_recording` (opens the recording by path)."""
    return _render_recording(*job)


def _render_recording(ri: int, rec_path: str, val, out_dir: str, config: DetectionConfig,
                      rec=None, progress=None) -> dict:
    """Write the images and labels of recording ``ri``; ``val`` is its split (bool) or,
    split by observer, {observer id: bool}. Returns its counts, class counts and look rows."""
    from dashtraj.datasets.drive import Drive

    if rec is None:
        rec = open_recording_or_drive(rec_path)
    out = Path(out_dir)
    w, h = config.size
    counts = {s: {"images": 0, "labels": 0, "background": 0} for s in ("train", "val")}
    class_counts = np.zeros(15, np.int64)
    look_rows: list[dict] = []
    look_for = None
    if config.randomize:
        from dashtraj.render.randomize import frame_rng, random_look

        def look_for(o, k):
            return random_look(frame_rng(config.randomize_seed, ri, o, k))
    if isinstance(rec, Drive):  # its images and truth boxes, scaled to the set's size
        frames = source_frames(rec, config.every_s)
        fw, fh = rec.config.camera.width_px, rec.config.camera.height_px
    else:
        frames = recording_frames(rec, config.every_s, (w, h), look_for=look_for)
        fw, fh = w, h
    for rf in frames:
        is_val = val[rf.observer_id] if isinstance(val, dict) else val
        split = "val" if is_val else "train"
        stem = f"r{ri:02d}_{rec.path.name}_o{rf.observer_id}_{rf.frame:06d}"
        lines = yolo_lines(rf.frame_data.labels, fw, fh, config.min_box_height_px * fh / h,
                           config.max_occlusion)
        rgb = rf.frame_data.rgb
        if (fw, fh) != (w, h):
            from PIL import Image

            rgb = np.asarray(Image.fromarray(rgb).resize((w, h), Image.Resampling.BOX))
        (out / "images" / split / f"{stem}.jpg").write_bytes(encode_jpeg(rgb))
        (out / "labels" / split / f"{stem}.txt").write_text(
            "".join(f"{ln}\n" for ln in lines), encoding="utf-8")
        if config.randomize:
            look_rows.append({"image": f"images/{split}/{stem}.jpg",
                              **look_for(rf.observer_id, rf.frame).flat()})
        counts[split]["images"] += 1
        counts[split]["labels"] += len(lines)
        counts[split]["background"] += int(not lines)
        for ln in lines:
            class_counts[int(ln.split()[0])] += 1
        if progress is not None:
            progress()
    return {"counts": counts, "class_counts": class_counts, "looks": look_rows}


def _write_looks(out: Path, rows: list[dict], seed: int) -> dict:
    """Write ``looks.parquet`` (image + the drawn look's columns, ``LookConfig.flat``)
    and return the ``dataset.json`` entry that describes it."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from dashtraj.render.randomize import describe

    cols = list(rows[0]) if rows else ["image"]
    pq.write_table(pa.table({c: [r[c] for r in rows] for c in cols}), out / "looks.parquet")
    return {"seed": int(seed), "per": "image", "looks": "looks.parquet", "ranges": describe()}
