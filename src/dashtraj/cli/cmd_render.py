"""`dashtraj render`, `dashtraj detection-dataset`, `dashtraj reid-dataset`."""

from __future__ import annotations

import argparse
import json
import sys

from dashtraj.cli._args import (
    count,
    fraction,
    image_size,
    int_at_least,
    non_negative_float,
    positive_float,
    positive_int,
)
from dashtraj.cli._args import seed as seed_int
from dashtraj.outputs import add_output_args


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `render`, `detection-dataset` and `reid-dataset` commands."""
    p = subparsers.add_parser(
        "render",
        help="render a recording's observer frames (JPEG) with a labels table",
        description=(
            "Render every observer's dashcam every --every seconds: DIR/<observer>/<frame>.jpg "
            "and DIR/labels.parquet (observer_id, t, vehicle_id, label, class id, visible "
            "and silhouette boxes, visible fraction, truncation, distance), and the camera "
            "poses and every vehicle's 3-D box (DIR/drive.json, poses.csv, map.xodr, "
            "truth.csv): DIR is a drive, which dashtraj perceive reads from its images like a "
            "real one; --depth adds each frame's depth image as CARLA's depth camera encodes "
            "it (DIR/<observer>/<frame>.depth.png), which tightens the drive's truth boxes "
            "to the vehicles' pixels. --preview adds "
            "DIR/preview/ PNGs with boxes and a contact sheet of crops per vehicle."
        ),
    )
    p.add_argument("recording", metavar="RUN", help="recording directory")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output directory")
    p.add_argument("--observer", type=count, action="append", metavar="ID",
                   help="only this observer (repeatable; default all)")
    p.add_argument("--every", type=positive_float, default=0.5, metavar="S",
                   help="sampling period, seconds (default 0.5)")
    p.add_argument("--size", type=image_size, default=None, metavar="WxH",
                   help="image size (default: the recording's camera)")
    p.add_argument("--png", action="store_true",
                   help="write the frames as PNG (lossless) instead of JPEG")
    p.add_argument("--depth", action="store_true",
                   help="also write each frame's depth (DIR/<observer>/<frame>.depth.png, "
                        "CARLA's depth camera encoding)")
    p.add_argument("--preview", action="store_true",
                   help="also write preview pictures, and preview/look_sheet.png: frames before "
                        "and after the realistic look (and a randomized one)")
    p.add_argument("--compare", metavar="DIR", default=None,
                   help="with --preview: reference frames (e.g. CARLA's) shown beside ours, "
                        "the nearest layout for each row")
    add_output_args(p)
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=run_render)

    d = subparsers.add_parser(
        "detection-dataset",
        help="render recordings into a YOLO detection set (15 classes)",
        description=(
            "YOLO set: images/{train,val}, labels/{train,val} (class cx cy w h of visible "
            "boxes, normalised), data.yaml, dataset.json. Split by recording (by observer "
            "with one recording). Vehicles lower than --min-box-height or more occluded "
            "than --max-occlusion stay unlabelled in the image (YOLO sees background). A "
            "drive with truth.csv (CARLA's frames from carla-record: labels from the "
            "vehicles' boxes and the depth camera) gives its own images, scaled to --size."
        ),
    )
    d.add_argument("recordings", nargs="+", metavar="RUN",
                   help="recording directories, or drives with truth.csv")
    d.add_argument("-o", "--output", required=True, metavar="DIR", help="output directory")
    d.add_argument("--every", type=positive_float, default=0.5, metavar="S",
                   help="sampling period, seconds (default 0.5)")
    d.add_argument("--size", type=image_size, default="640x360", metavar="WxH",
                   help="image size (640x360)")
    d.add_argument("--min-box-height", type=non_negative_float, default=10.0, metavar="PX",
                   help="smallest labelled visible box height, pixels (default 10)")
    d.add_argument("--max-occlusion", type=fraction, default=0.7,
                   help="largest labelled occlusion 1 - visible fraction (default 0.7)")
    d.add_argument("--val-fraction", type=fraction, default=0.2,
                   help="share of recordings in val (default 0.2)")
    d.add_argument("--seed", type=seed_int, default=0, help="split seed (default 0)")
    d.add_argument("--train-only", nargs="+", default=[], metavar="RUN",
                   help="more recordings, all in train: the RUNs' split stays what it is "
                        "without them (a set grows its training part, keeps its val)")
    _randomize_args(d, "image")
    d.add_argument("--workers", type=positive_int, default=1,
                   help="render processes, one recording each at a time (default 1; the "
                        "same files for any count)")
    add_output_args(d)
    d.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    d.add_argument("--json", action="store_true", help="print the summary as JSON")
    d.set_defaults(func=run_detection)

    r = subparsers.add_parser(
        "reid-dataset",
        help="render a VeRi-layout ReID set (identities seen by a ring of fixed cameras)",
        description=(
            "After the paper's CARLA ReID dataset: every identity alone on a straight road "
            "of a town, seen by --cameras fixed cameras around it; crops in the VeRi-776 "
            "layout (image_train, image_query, image_test, name_*.txt, reid.json). The last "
            "--test-ids identities are test. --from-recordings adds image_query_moving/ "
            "(test identities seen by moving observers)."
        ),
    )
    r.add_argument("-o", "--output", required=True, metavar="DIR", help="output directory")
    r.add_argument("--ids", type=positive_int, default=700, help="identities (default 700)")
    r.add_argument("--cameras", type=positive_int, default=85, help="ring cameras (default 85)")
    r.add_argument("--test-ids", type=positive_int, default=None,
                   help="test identities (default round(ids * 50 / 700), at least 1)")
    r.add_argument("--size", type=int_at_least(16), default=256, metavar="PX",
                   help="crop long side, pixels, 16 or more (default 256)")
    r.add_argument("--town", default="town10", help="built-in town of the stage (town10)")
    r.add_argument("--fov", default="90", metavar="DEG|zoom",
                   help="horizontal FOV of every ring camera, degrees (default 90, a fixed lens "
                        "as the paper's cameras); 'zoom' fits a FOV per camera instead")
    r.add_argument("--image-size", type=image_size, default="800x600", metavar="WxH",
                   help="ring camera image size with a fixed FOV (default 800x600)")
    r.add_argument("--seed", type=seed_int, default=0, help="camera and split seed (default 0)")
    _randomize_args(r, "ring image (or --randomize-per identity)")
    r.add_argument("--randomize-per", choices=("image", "identity"), default="image",
                   help="draw the scene look (weather, sun, scene colours) per ring image "
                        "(default) or once per identity, shared by its cameras (a look cue "
                        "tied to the identity)")
    r.add_argument("--test-only", action="store_true",
                   help="render only the test identities (query and gallery): an "
                        "evaluation set, e.g. in another look")
    r.add_argument("--workers", type=positive_int, default=1, help="render processes (default 1)")
    r.add_argument("--from-recordings", nargs="+", default=(), metavar="RUN",
                   help="recordings whose observers' crops make image_query_moving/")
    add_output_args(r)
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    r.add_argument("--json", action="store_true", help="print the summary as JSON")
    r.set_defaults(func=run_reid)


def _randomize_args(p: argparse.ArgumentParser, per: str) -> None:
    p.add_argument("--randomize", action="store_true",
                   help=f"domain randomization: draw weather, sun, scene colours, textures and "
                        f"camera effects per {per} within the ranges of "
                        "dashtraj.render.randomize; the draws go to looks.parquet")
    p.add_argument("--randomize-seed", type=seed_int, default=0, metavar="N",
                   help="seed of the --randomize draws (default 0)")


def _bar(args, total: int, unit: str):
    if args.quiet or not sys.stderr.isatty():
        return None
    from tqdm import tqdm

    return tqdm(total=total, unit=unit, file=sys.stderr)


def _frame_total(recordings, every_s: float, observers=None) -> int:
    from dashtraj.datasets.drive import Drive
    from dashtraj.datasets.frames import observer_ids, sample_steps

    n = 0
    for rec in recordings:
        obs = observers or observer_ids(rec)
        if isinstance(rec, Drive):
            n += rec.frame_count(every_s, obs)
        else:
            n += len(sample_steps(rec, every_s)) * len(obs)
    return n


def run_render(args: argparse.Namespace) -> int:
    """Render one recording's frames; prints a summary; returns 0."""
    from pathlib import Path

    from dashtraj.datasets.frames import export_frames, observer_ids, parse_size
    from dashtraj.outputs import atomic_output, check_output
    from dashtraj.world.recording import Recording

    out = check_output(args.output, overwrite=args.overwrite, kind="dir")
    size = parse_size(args.size) if args.size else None
    rec = Recording.open(args.recording)
    if args.observer:
        known = observer_ids(rec)
        unknown = sorted(set(args.observer) - set(known))
        if unknown:
            from dashtraj.cli._args import ArgumentError

            raise ArgumentError(f"--observer {unknown[0]}: not an observer of {rec.path} "
                                f"(observers: {', '.join(map(str, known))})")
    if args.compare is not None:  # checked before hours of rendering, not after
        from dashtraj.cli._args import ArgumentError
        from dashtraj.datasets.look_sheet import reference_images

        if not args.preview:
            raise ArgumentError("--compare needs --preview (it adds a column to the look sheet)")
        reference_images(args.compare)
    bar = _bar(args, _frame_total([rec], args.every, args.observer), "frame")
    try:
        with atomic_output(out, overwrite=args.overwrite, kind="dir") as tmp:
            s = export_frames(rec, tmp, args.every, size, args.observer, args.preview,
                              progress=bar.update if bar is not None else None,
                              compare_dir=args.compare,
                              image_format="png" if args.png else "jpg",
                              depth=args.depth)
    finally:
        if bar is not None:
            bar.close()

    def final(p: Path | None) -> Path | None:  # the paths inside the moved folder
        return None if p is None else out / Path(p).relative_to(tmp)

    labels_path, preview_dir = final(s.labels_path), final(s.preview_dir)
    info = {"output": str(out), "frames": s.frames, "labels": s.labels,
            "in_view": s.in_view, "per_observer": {str(k): v for k, v in s.per_observer.items()},
            "labels_path": str(labels_path),
            "preview": str(preview_dir) if preview_dir else None}
    if args.json:
        print(json.dumps(info))
    else:
        obs = ", ".join(f"{k}: {v}" for k, v in s.per_observer.items())
        print(f"{out}: {s.frames} frames ({obs}), {s.labels} labels "
              f"({s.in_view} with visible pixels) in {labels_path.name}"
              + (f"; previews in {preview_dir}" if preview_dir else ""))
    return 0


def run_detection(args: argparse.Namespace) -> int:
    """Build a YOLO detection set; prints a summary; returns 0."""
    from pathlib import Path

    from dashtraj.datasets.detection import (
        DetectionConfig,
        build_detection_dataset,
        data_yaml,
        open_recording_or_drive,
    )
    from dashtraj.datasets.frames import parse_size
    from dashtraj.outputs import atomic_output, check_output

    out = check_output(args.output, overwrite=args.overwrite, kind="dir")
    cfg = DetectionConfig(every_s=args.every, size=parse_size(args.size),
                          min_box_height_px=args.min_box_height,
                          max_occlusion=args.max_occlusion, val_fraction=args.val_fraction,
                          seed=args.seed, randomize=args.randomize,
                          randomize_seed=args.randomize_seed)
    seen: dict = {}
    for p in [*args.recordings, *args.train_only]:
        # one recording twice would put the same frames in train and val
        key = Path(p).resolve()
        if key in seen:
            from dashtraj.cli._args import ArgumentError

            raise ArgumentError(f"recording {p} is given twice (also as {seen[key]}); "
                                "each recording once, or its frames leak between train and val")
        seen[key] = p
    recs = [open_recording_or_drive(p) for p in args.recordings]
    extra = [open_recording_or_drive(p) for p in args.train_only]
    parallel = args.workers > 1 and len(recs) + len(extra) > 1
    bar = _bar(args, len(recs) + len(extra) if parallel
               else _frame_total([*recs, *extra], args.every),
               "recording" if parallel else "frame")
    try:
        with atomic_output(out, overwrite=args.overwrite, kind="dir") as tmp:
            info = build_detection_dataset(recs, tmp, cfg,
                                           progress=bar.update if bar is not None else None,
                                           workers=args.workers, train_only=extra)
            # data.yaml names the set's folder: the final one, not the temporary sibling
            (tmp / "data.yaml").write_text(data_yaml(out), encoding="utf-8")
    finally:
        if bar is not None:
            bar.close()
    if args.json:
        print(json.dumps(info))
    else:
        c = info["counts"]
        print(f"{args.output}: train {c['train']['images']} images / {c['train']['labels']} "
              f"boxes, val {c['val']['images']} images / {c['val']['labels']} boxes; split by "
              f"{info['split_by']} (val: {', '.join(map(str, info['val'])) or 'none'})")
        if "warning" in info:
            print(f"warning: {info['warning']}", file=sys.stderr)
    return 0


def run_reid(args: argparse.Namespace) -> int:
    """Build a VeRi-layout ReID set; prints a summary; returns 0."""
    from dashtraj.datasets.frames import DatasetError, parse_size
    from dashtraj.datasets.reid import ReidConfig, build_reid_dataset
    from dashtraj.outputs import atomic_output, check_output
    from dashtraj.world.recording import Recording

    out = check_output(args.output, overwrite=args.overwrite, kind="dir")
    if args.test_ids is not None and args.test_ids >= args.ids:
        from dashtraj.cli._args import ArgumentError

        raise ArgumentError(f"--test-ids {args.test_ids} must be fewer than --ids {args.ids} "
                            "(at least one train identity)")
    if args.fov == "zoom":
        fov = None
    else:
        try:
            fov = float(args.fov)
        except ValueError:
            fov = float("nan")
        if not 1.0 <= fov <= 170.0:
            raise DatasetError(f"--fov {args.fov!r}: degrees in [1, 170] or 'zoom'")
    cfg = ReidConfig(n_ids=args.ids, n_cameras=args.cameras, size=args.size, seed=args.seed,
                     n_test_ids=args.test_ids, town=args.town, randomize=args.randomize,
                     randomize_seed=args.randomize_seed, fov_deg=fov,
                     image_size=parse_size(args.image_size),
                     randomize_per=args.randomize_per, test_only=args.test_only)
    recs = [Recording.open(p) for p in args.from_recordings]
    bar = _bar(args, cfg.test_ids if args.test_only else args.ids, "id")
    try:
        with atomic_output(out, overwrite=args.overwrite, kind="dir") as tmp:
            info = build_reid_dataset(cfg, tmp, workers=args.workers, recordings=recs,
                                      progress=bar.update if bar is not None else None)
    finally:
        if bar is not None:
            bar.close()
    if args.json:
        print(json.dumps(info["counts"]))
    else:
        c = info["counts"]
        line = (f"{args.output}: train {c['train']['images']} images of {c['train']['ids']} ids; "
                f"query {c['query']['images']}, gallery {c['test']['images']} of "
                f"{c['test']['ids']} test ids")
        if "query_moving" in c:
            m = c["query_moving"]
            line += f"; moving query {m['images']} images of {m['ids']} ids"
        print(line + f"; ids are identity_id + 1 (see {args.output}/reid.json)")
    return 0
