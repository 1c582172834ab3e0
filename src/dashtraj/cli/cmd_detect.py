"""`dashtraj detect` (run a YOLO ONNX detector on images) and `dashtraj detector`
(train | export | eval the vehicle detector)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from dashtraj.cli._args import fraction, image_size, int_at_least, positive_float, seed
from dashtraj.outputs import add_output_args
from dashtraj.train.detector_recipes import RECIPES

positive_int = int_at_least(1)
non_negative_int = int_at_least(0)
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp")


def add_classifier_arg(p, scope: str = "") -> None:
    """``--classifier shipped|M.onnx|none``: the detector's second stage (``scope`` starts
    its help)."""
    p.add_argument("--classifier", default="none", metavar="shipped|M.onnx|none",
                   help=f"{scope}second stage of a detector model: each box's class read "
                        "from its crop by a box classifier, which also drops background "
                        "and moves the box's sides (shipped: the one beside the shipped "
                        "detector; default none: the detector's own boxes and classes)")


def add_refine_steps_arg(p) -> None:
    """``--refine-steps N``: how often a refining box classifier moves each box."""
    from dashtraj.perception.detect import REFINE_STEPS

    p.add_argument("--refine-steps", type=int_at_least(1), default=REFINE_STEPS, metavar="N",
                   help="a refining --classifier moves each box N times, each from the crop "
                        f"of the box it moved to (default {REFINE_STEPS})")


def add_classifier_flip_arg(p) -> None:
    """``--classifier-flip`` / ``--no-classifier-flip``: the box classifier reads each crop
    mirrored too (test-time augmentation)."""
    from dashtraj.perception.detect import CLASSIFIER_FLIP

    p.add_argument("--classifier-flip", action=argparse.BooleanOptionalAction,
                   default=CLASSIFIER_FLIP,
                   help="the --classifier reads each crop mirrored too and averages the two "
                        f"(default {'on' if CLASSIFIER_FLIP else 'off'})")


def classifier_flip_used(det) -> bool | None:
    """Whether a `YoloDetector`'s box classifier reads crops mirrored too, for a command's
    JSON; None without a box classifier."""
    return None if det.classifier is None else det.classifier.flip


def refine_steps_used(det) -> int | None:
    """A `YoloDetector`'s refining steps, for a command's JSON; None without a refining
    box classifier."""
    staged = det.classifier is not None and det.classifier.refines
    return det.refine_steps if staged else None


def shipped_or_file(flag: str, value: str, shipped) -> str:
    """``value`` of a model argument: "shipped" names the ``shipped`` path, anything else a
    file that must exist (one-line error naming ``flag``)."""
    from dashtraj.cli._args import require_file

    if value == "shipped":
        return str(shipped)
    require_file(flag, value)
    return value


def classifier_path_from_arg(value: str) -> str | None:
    """The box classifier file that ``--classifier`` names, or None (one-line error on a
    missing file)."""
    from dashtraj.perception.detect import default_classifier_path

    if value == "none":
        return None
    return shipped_or_file("--classifier", value, default_classifier_path())


def classifier_from_arg(value: str, flip: bool | None = None):
    """The `BoxClassifier` that ``--classifier`` names (``flip``: ``--classifier-flip``;
    None: the default), or None."""
    from dashtraj.perception.detect import CLASSIFIER_FLIP, BoxClassifier

    path = classifier_path_from_arg(value)
    return None if path is None else BoxClassifier(
        path, flip=CLASSIFIER_FLIP if flip is None else flip)


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `detect` and `detector` commands."""
    d = subparsers.add_parser(
        "detect",
        help="detect vehicles in an image or a folder of images (ONNX, no torch)",
        description=(
            "Run a YOLO ONNX detector (ultralytics v8/11 output layout; default: the shipped "
            "15-class vehicle detector) on IMAGE or every image in DIR. Writes OUT/labels/"
            "<stem>.txt (YOLO lines: class cx cy w h score, normalised) and OUT/detections."
            "json; --preview adds OUT/preview/<stem>.jpg with the boxes drawn."
        ),
    )
    d.add_argument("source", metavar="IMAGE_OR_DIR", help="an image or a folder of images")
    d.add_argument("--model", default=None, metavar="M.onnx",
                   help="ONNX model (default: the shipped detector)")
    d.add_argument("--names", default=None, metavar="data.yaml",
                   help="class names (default: the model's metadata)")
    d.add_argument("--conf", type=fraction, default=0.25, help="score threshold (0.25)")
    d.add_argument("--iou", type=fraction, default=0.6, help="NMS IoU threshold (0.6)")
    d.add_argument("--batch", type=positive_int, default=8, help="images per run (8)")
    d.add_argument("-o", "--output", required=True, metavar="OUT", help="output folder")
    d.add_argument("--preview", action="store_true", help="also draw the boxes")
    add_classifier_arg(d)
    add_refine_steps_arg(d)
    add_classifier_flip_arg(d)
    d.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_output_args(d)
    d.set_defaults(func=run_detect)

    p = subparsers.add_parser("detector", help="train, export or evaluate the vehicle detector",
                              description="Train (needs the .[train] extra), export or "
                              "evaluate the 15-class vehicle detector.")
    sub = p.add_subparsers(dest="detector_command", metavar="ACTION", required=True)
    t = sub.add_parser(
        "train", help="train on a YOLO set (needs pip install -e '.[train]')",
        description=(
            "Train the EfficientNet-Lite0 detector on a set made by 'dashtraj "
            "detection-dataset'. Writes DIR/last.pt (every 50 steps; a rerun resumes from "
            "it), DIR/best.pt (best validation mAP50-95), DIR/log.jsonl, DIR/steps.jsonl, "
            "DIR/curves.png, DIR/recipe.json. Recipes: cpu (2 CPU cores), gpu (whole "
            "frames, the whole backbone trained; for a GPU) and paper (the paper's "
            "schedule, for a GPU)."
        ),
    )
    t.add_argument("data", metavar="DATA", help="YOLO set folder (data.yaml, images/, labels/)")
    t.add_argument("-o", "--output", required=True, metavar="DIR", help="run folder")
    t.add_argument("--recipe", choices=tuple(RECIPES), default="cpu",
                   help="cpu, gpu or paper (default cpu)")
    t.add_argument("--seed", type=seed, default=0, help="seed (default 0)")
    t.add_argument("--epochs", type=positive_int, default=None,
                   help="override the recipe's epoch count")
    t.add_argument("--stop-after-epoch", type=positive_int, default=None, metavar="N",
                   help="stop after epoch N, keeping the schedule of --epochs (a fixed "
                   "budget; a rerun without it resumes to the end)")
    t.add_argument("--max-images", type=positive_int, default=None,
                   help="use only the first N images of each split (smoke tests)")
    t.add_argument("--workers", type=non_negative_int, default=0,
                   help="data-loading processes (default 0: in the training process; the "
                   "same batches for any count)")
    t.add_argument("--json", action="store_true", help="print the summary as JSON")
    t.set_defaults(func=run_train)

    c = sub.add_parser(
        "train-classifier", help="train the second stage, a box classifier (needs '.[train]')",
        description=(
            "Train the box classifier (dashtraj.train.box_classifier: each labelled box's "
            "crop, an EfficientNet-Lite0 from its ImageNet weights, every layer trained) on a "
            "set made by 'dashtraj detection-dataset' (render it at the frames' size, e.g. "
            "--size 1280x720). Writes DIR/last.pt after every epoch (a rerun resumes from "
            "it), DIR/log.jsonl, DIR/crops.npz and, at the end, DIR/classifier.onnx."),
    )
    c.add_argument("data", metavar="DATA", help="YOLO set folder (data.yaml, images/, labels/)")
    c.add_argument("-o", "--output", required=True, metavar="DIR", help="run folder")
    c.add_argument("--epochs", type=positive_int, default=8, help="epochs (default 8)")
    c.add_argument("--seed", type=seed, default=0, help="seed (default 0)")
    c.add_argument("--threads", type=positive_int, default=2, help="torch threads (default 2)")
    c.add_argument("--blocks", type=int_at_least(1), default=None, metavar="N",
                   help="EfficientNet-Lite0 blocks kept, of 16 (default: "
                        "dashtraj.train.box_classifier.BLOCKS)")
    c.add_argument("--refine-with", default=None, metavar="shipped|M.onnx",
                   help="also learn a background class and box refinement, on this "
                   "detector's proposals over the set's images (shipped: the shipped "
                   "detector; default: classes only, on the labelled boxes)")
    c.add_argument("--lowres", type=fraction, default=0.0, metavar="P",
                   help="share of training crops drawn as a frame of 1/1.5-1/3 the "
                   "resolution would show them (default 0)")
    c.add_argument("--json", action="store_true", help="print the summary as JSON")
    c.set_defaults(func=run_train_classifier)

    e = sub.add_parser("export", help="export a checkpoint to ONNX",
                       description="Write a training checkpoint's EMA weights as ONNX "
                       "(ultralytics layout, class names in the metadata).")
    e.add_argument("checkpoint", metavar="CKPT.pt")
    e.add_argument("-o", "--output", required=True, metavar="M.onnx")
    add_output_args(e)
    e.set_defaults(func=run_export)
    register_eval(sub)
    register_eval_external(sub)


def _training_module(data, subdir: str, command: str, module: str):
    """``module`` (a `dashtraj.train` module) for a command that trains on a YOLO set, once
    the set has ``subdir``/train/ and the training extra imports; DashtrajError otherwise."""
    import importlib

    from dashtraj.errors import DashtrajError

    if not (Path(data) / subdir / "train").is_dir():
        raise DashtrajError(f"{data}: no {subdir}/train/ (expected a YOLO set made by "
                            "'dashtraj detection-dataset')")
    try:
        importlib.import_module("torch")
        return importlib.import_module(module)
    except ImportError as exc:
        raise DashtrajError(f"{command} needs the training extra ({exc.name} is "
                            "missing): pip install -e '.[train]'") from None


def run_train(args: argparse.Namespace) -> int:
    """Train or resume; prints a summary."""
    train = _training_module(args.data, "images", "detector train",
                             "dashtraj.train.detector_train").train
    from dashtraj.train.detector_recipes import get_recipe

    recipe = get_recipe(args.recipe)

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)
        with open(Path(args.output) / "train.log", "a", encoding="utf-8") as fh:
            fh.write(msg + "\n")

    Path(args.output).mkdir(parents=True, exist_ok=True)
    s = train(args.data, args.output, recipe, seed=args.seed, epochs=args.epochs,
              max_images=args.max_images, stop_after=args.stop_after_epoch, log=log,
              workers=args.workers)
    if args.json:
        print(json.dumps(s))
    else:
        print(f"{args.output}: {s['epochs']} epochs, {s['steps']} steps, best val mAP50-95 "
              f"{s['best_map50_95']:.3f}, {s['wall_s'] / 60:.1f} min")
    return 0


def run_train_classifier(args: argparse.Namespace) -> int:
    """Train (or resume) the box classifier and export it; prints a summary."""
    if args.blocks is not None and args.blocks > 16:
        from dashtraj.cli._args import ArgumentError

        raise ArgumentError(f"--blocks {args.blocks}: EfficientNet-Lite0 has 16 blocks")
    from dashtraj.perception.detect import default_model_path

    detector = None if args.refine_with is None else \
        shipped_or_file("--refine-with", args.refine_with, default_model_path())
    bc = _training_module(args.data, "labels", "detector train-classifier",
                          "dashtraj.train.box_classifier")
    out = Path(args.output)
    s = bc.train(args.data, out, epochs=args.epochs, seed=args.seed, threads=args.threads,
                 blocks=args.blocks or bc.BLOCKS, detector=detector, lowres=args.lowres,
                 log=lambda m: print(m, file=sys.stderr, flush=True))
    tmp = out / "classifier.tmp.onnx"
    bc.export_onnx(out / "last.pt", tmp)
    tmp.replace(out / "classifier.onnx")
    s["onnx"] = str(out / "classifier.onnx")
    if args.json:
        print(json.dumps(s))
    else:
        v = s.get("val", {})
        print(f"{out / 'classifier.onnx'}: {s.get('epoch')} epochs, validation accuracy "
              f"{v.get('acc', float('nan')):.3f} (vehicle {v.get('vehicle_acc', float('nan')):.3f},"
              f" orientation {v.get('orientation_acc', float('nan')):.3f})")
    return 0


def run_export(args: argparse.Namespace) -> int:
    """Export a checkpoint to ONNX; prints the size and sha256."""
    import hashlib

    from dashtraj.errors import DashtrajError
    from dashtraj.outputs import atomic_output, check_output

    if not Path(args.checkpoint).is_file():
        raise DashtrajError(f"{args.checkpoint}: no such checkpoint (DIR/best.pt or "
                            "DIR/last.pt of 'dashtraj detector train')")
    check_output(args.output, overwrite=args.overwrite, kind="file")
    try:
        from dashtraj.train.detector_train import export_checkpoint
    except ImportError as exc:
        raise DashtrajError(f"detector export needs the training extra ({exc.name} is "
                            "missing): pip install -e '.[train]'") from None
    with atomic_output(args.output, overwrite=args.overwrite, kind="file") as tmp:
        info = export_checkpoint(args.checkpoint, tmp)
    data = Path(args.output).read_bytes()
    print(f"{args.output}: {len(data) / 1e6:.2f} MB, sha256 {hashlib.sha256(data).hexdigest()}, "
          f"input {info['imgsz'][0]}x{info['imgsz'][1]}, {len(info['names'])} classes, "
          f"epoch {info['epoch']}")
    return 0


def _list_images(source: Path) -> list[Path]:
    from dashtraj.perception.detect import DetectorError

    if source.is_file():
        return [source]
    if source.is_dir():
        imgs = sorted(p for p in source.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not imgs:
            raise DetectorError(f"{source}: no images ({', '.join(IMAGE_SUFFIXES)})")
        return imgs
    raise DetectorError(f"{source}: no such image or folder")


def run_detect(args: argparse.Namespace) -> int:
    """Detect in images; writes YOLO txt (+ previews); prints a summary."""
    from dashtraj.outputs import atomic_output, check_output
    from dashtraj.perception.detect import YoloDetector, read_rgb

    check_output(args.output, overwrite=args.overwrite, kind="dir")
    det = YoloDetector(args.model, names=args.names, conf=args.conf, iou=args.iou,
                       batch=args.batch,
                       classifier=classifier_from_arg(args.classifier, args.classifier_flip),
                       refine_steps=args.refine_steps)
    images = _list_images(Path(args.source))
    summary = {"images": 0, "detections": 0, "per_class": {}}
    with atomic_output(args.output, overwrite=args.overwrite, kind="dir") as tmp:
        (tmp / "labels").mkdir()
        if args.preview:
            (tmp / "preview").mkdir()
        records = []
        for i in range(0, len(images), args.batch):
            paths = images[i:i + args.batch]
            frames = [read_rgb(p) for p in paths]
            for p, rgb, d in zip(paths, frames, det.detect(frames), strict=True):
                h, w = rgb.shape[:2]
                (tmp / "labels" / f"{p.stem}.txt").write_text(
                    "".join(f"{ln}\n" for ln in d.yolo_lines(w, h)), encoding="utf-8")
                records.append({"image": str(p), "width": w, "height": h, "detections": [
                    {"box": [round(float(v), 2) for v in b], "score": round(float(s), 4),
                     "class_id": int(c), "label": det.names[int(c)]}
                    for b, s, c in zip(d.boxes, d.scores, d.class_ids, strict=True)]})
                summary["images"] += 1
                summary["detections"] += len(d)
                for lab in d.labels:
                    summary["per_class"][lab] = summary["per_class"].get(lab, 0) + 1
                if args.preview:
                    draw_detections(rgb, d).save(tmp / "preview" / f"{p.stem}.jpg", quality=90)
        (tmp / "detections.json").write_text(
            json.dumps({"model": str(det.path), "classifier": None if det.classifier is None
                        else str(det.classifier.path), "refine_steps": refine_steps_used(det),
                        "classifier_flip": classifier_flip_used(det),
                        "names": list(det.names), "conf": args.conf,
                        "iou": args.iou, "images": records}, indent=1) + "\n",
            encoding="utf-8")
    summary["output"] = args.output
    if args.json:
        print(json.dumps(summary))
    else:
        per = ", ".join(f"{k} {v}" for k, v in sorted(summary["per_class"].items()))
        print(f"{args.output}: {summary['detections']} detections in {summary['images']} "
              f"images" + (f" ({per})" if per else "")
              + ("; previews in preview/" if args.preview else ""))
    return 0


def draw_detections(rgb, det):
    """A PIL image of the frame with each detection's box, label and score."""
    from PIL import Image, ImageDraw

    im = Image.fromarray(rgb)
    dr = ImageDraw.Draw(im)
    palette = [(230, 25, 75), (60, 180, 75), (255, 225, 25), (0, 130, 200), (245, 130, 48)]
    for (x0, y0, x1, y1), s, c in zip(det.boxes, det.scores, det.class_ids, strict=True):
        col = palette[int(c) // 3 % len(palette)]
        dr.rectangle([x0, y0, x1, y1], outline=col, width=2)
        dr.text((x0 + 2, max(0, y0 - 11)), f"{det.names[int(c)]} {s:.2f}", fill=col)
    return im


def register_eval(sub) -> None:
    """The `detector eval` action."""
    v = sub.add_parser(
        "eval", help="score a detector on recordings' rendered frames",
        description=(
            "Render the recordings' observer frames (use held-out recordings: seeds and "
            "towns never used in training), run the detector and score it against the "
            "renderer's exact visible boxes: mAP50, mAP50-95 (COCO 101-point), AP per class, "
            "precision/recall at --conf, for all boxes and for boxes >= --small-px tall. "
            "Vehicles the detection set leaves unlabelled, and vehicles more than "
            "--max-truncation outside the frame, are ignore regions."
        ),
    )
    v.add_argument("recordings", nargs="+", metavar="RUN",
                   help="recording directories, or drives with truth.csv (their images "
                        "scored against their truth boxes; record them with depth)")
    v.add_argument("--model", default=None, metavar="M.onnx",
                   help="ONNX model (default: the shipped detector)")
    v.add_argument("--names", default=None, metavar="data.yaml",
                   help="class names (default: the model's metadata)")
    v.add_argument("--every", type=positive_float, default=2.0, metavar="S",
                   help="sampling period, seconds (default 2)")
    v.add_argument("--size", type=image_size, default=None, metavar="WxH",
                   help="frame size (default: the recordings' camera, 1280x720)")
    v.add_argument("--conf", type=fraction, default=0.25,
                   help="threshold of the precision/recall figures (0.25)")
    v.add_argument("--small-px", type=positive_float, default=24.0, metavar="PX",
                   help="the size subset: boxes at least this tall (24)")
    v.add_argument("--max-truncation", type=fraction, default=0.5, metavar="F",
                   help="vehicles with more than this share of their silhouette outside the "
                   "frame are ignore regions (KITTI's hard level: 0.5; 1: none)")
    v.add_argument("-o", "--output", default=None, metavar="DIR",
                   help="write DIR/eval.json (and DIR/ap_per_class.png with --plot)")
    v.add_argument("--plot", action="store_true",
                   help="bar chart of AP50 per class (needs -o)")
    add_classifier_arg(v)
    add_refine_steps_arg(v)
    add_classifier_flip_arg(v)
    v.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    v.add_argument("--json", action="store_true", help="print the results as JSON")
    add_output_args(v)
    v.set_defaults(func=run_eval)


def run_eval(args: argparse.Namespace) -> int:
    """Evaluate; prints a table (or JSON)."""
    from dashtraj.cli._args import ArgumentError, progress_bar
    from dashtraj.datasets.frames import parse_size
    from dashtraj.outputs import atomic_output, check_output
    from dashtraj.perception.detect import YoloDetector
    from dashtraj.perception.detector_eval import EvalConfig, evaluate_recordings, plot_per_class
    from dashtraj.perception.evaluate import open_recording

    if args.plot and not args.output:
        raise ArgumentError("--plot needs -o DIR")
    if args.output:
        check_output(args.output, overwrite=args.overwrite, kind="dir")
    recs = [open_recording(p) for p in args.recordings]
    size = parse_size(args.size) if args.size else None
    w = size[0] if size else recs[0].config.camera.width_px
    cfg = EvalConfig(every_s=args.every, size=size, min_box_height_px=10.0 * w / 640,
                     small_px=args.small_px * w / 1280, conf=args.conf,
                     max_truncation=args.max_truncation)
    det = YoloDetector(args.model, names=args.names, conf=0.001, iou=0.6,
                       classifier=classifier_from_arg(args.classifier, args.classifier_flip),
                       refine_steps=args.refine_steps)
    with progress_bar(args.quiet, unit="frame") as progress:
        res = evaluate_recordings(recs, det, cfg, progress=progress)
    res["classifier"] = None if det.classifier is None else str(det.classifier.path)
    res["refine_steps"] = refine_steps_used(det)
    res["classifier_flip"] = classifier_flip_used(det)
    if args.output:
        with atomic_output(args.output, overwrite=args.overwrite, kind="dir") as tmp:
            (tmp / "eval.json").write_text(json.dumps(res, indent=1) + "\n", encoding="utf-8")
            if args.plot:
                plot_per_class(res, tmp / "ap_per_class.png")
    if args.json:
        print(json.dumps(res))
    else:
        print(format_table(res))
    return 0


def register_eval_external(sub) -> None:
    """The `detector eval-external` action."""
    v = sub.add_parser(
        "eval-external", help="score the detector on another source's frames (YOLO labels)",
        description=(
            "Score the detector on a folder of frames from another source (CARLA's, a "
            "real camera's) with YOLO labels: DIR/images/*.jpg|png and DIR/labels/*.txt "
            "('class cx cy w h', normalised), class names from DIR/data.yaml, "
            "DIR/classes.txt or --names. Our classes map to theirs by base class "
            "(--class-map; car/truck/bus -> vehicle, motorcycle -> motobike, bicycle -> "
            "bike), a class-aware NMS keeps one box per object after the mapping, and "
            "their unmapped classes (traffic lights, signs) are not scored. Reports AP50 "
            "and AP50-95 per mapped class and class-agnostic, for all boxes and boxes at "
            "least --small-px tall. A validation set: never train or tune on it."
        ),
    )
    v.add_argument("folder", metavar="DIR", help="folder with images/ and labels/")
    v.add_argument("--model", default=None, metavar="M.onnx",
                   help="ONNX model (default: the shipped detector)")
    v.add_argument("--names", default=None, metavar="A,B,...",
                   help="the set's class names in id order (default: DIR/data.yaml or "
                   "DIR/classes.txt)")
    v.add_argument("--class-map", default=None, metavar="OURS=THEIRS,...",
                   help="our base class -> their class (default car=vehicle,truck=vehicle,"
                   "bus=vehicle,motorcycle=motobike,bicycle=bike)")
    v.add_argument("--conf", type=fraction, default=0.25,
                   help="threshold of the precision/recall figures (0.25)")
    v.add_argument("--small-px", type=positive_float, default=24.0, metavar="PX",
                   help="the size subset: boxes at least this tall, the frames' pixels (24)")
    v.add_argument("--max-images", type=positive_int, default=None, metavar="N",
                   help="score only the first N images (sorted by name)")
    v.add_argument("-o", "--output", default=None, metavar="DIR",
                   help="write DIR/eval.json")
    add_classifier_arg(v)
    add_refine_steps_arg(v)
    add_classifier_flip_arg(v)
    v.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    v.add_argument("--json", action="store_true", help="print the results as JSON")
    add_output_args(v)
    v.set_defaults(func=run_eval_external)


def run_eval_external(args: argparse.Namespace) -> int:
    """Evaluate on another source's frames; prints a table (or JSON)."""
    from dashtraj.cli._args import ArgumentError, progress_bar
    from dashtraj.errors import DashtrajError
    from dashtraj.outputs import atomic_output, check_output
    from dashtraj.perception.detect import YoloDetector
    from dashtraj.perception.detector_eval import (
        evaluate_external,
        parse_class_map,
        read_external_names,
    )

    folder = Path(args.folder)
    if not folder.is_dir():
        raise DashtrajError(f"{folder}: no such folder")
    if args.output:
        check_output(args.output, overwrite=args.overwrite, kind="dir")
    if args.names:
        names = [n.strip() for n in args.names.split(",") if n.strip()]
        if not names:
            raise ArgumentError("--names: no class names")
    else:
        names = read_external_names(folder)
        if names is None:
            raise DashtrajError(f"{folder}: no data.yaml or classes.txt with the class names; "
                                "pass --names (e.g. vehicle,bike,motobike,traffic_light,"
                                "traffic_sign for CARLA's object detection set)")
    cmap = None
    if args.class_map:
        try:
            cmap = parse_class_map(args.class_map)
        except ValueError as exc:
            raise ArgumentError(f"--class-map: {exc}") from None
    det = YoloDetector(args.model, conf=0.001, iou=0.6,
                       classifier=classifier_from_arg(args.classifier, args.classifier_flip),
                       refine_steps=args.refine_steps)
    with progress_bar(args.quiet, unit="image") as progress:
        res = evaluate_external(folder, det, names, cmap, small_px=args.small_px,
                                conf=args.conf, max_images=args.max_images, progress=progress)
    res["classifier"] = None if det.classifier is None else str(det.classifier.path)
    res["refine_steps"] = refine_steps_used(det)
    res["classifier_flip"] = classifier_flip_used(det)
    if args.output:
        with atomic_output(args.output, overwrite=args.overwrite, kind="dir") as tmp:
            (tmp / "eval.json").write_text(json.dumps(res, indent=1) + "\n", encoding="utf-8")
    if args.json:
        print(json.dumps(res))
    else:
        print(format_external_table(res))
    return 0


def _ap_header(small) -> list[str]:
    return [f"| class | AP50 | AP50-95 | GT | AP50 >= {small:g}px | AP50-95 >= {small:g}px "
            "| GT >= px |", "|---|---|---|---|---|---|---|"]


def _ap_row(name: str, a: dict | None, b: dict | None) -> str:
    """One class's row: AP50 / AP50-95 / GT for all boxes (a) and the size subset (b)."""

    def f(d, k):
        return f"{d[k]:.3f}" if d is not None else "-"

    return (f"| {name} | {f(a, 'ap50')} | {f(a, 'ap50_95')} | {a['gt'] if a else 0} | "
            f"{f(b, 'ap50')} | {f(b, 'ap50_95')} | {b['gt'] if b else 0} |")


def format_external_table(res: dict) -> str:
    """A Markdown table: AP50 / AP50-95 / GT per mapped class and class-agnostic."""
    small = res.get("small_px", 24)
    lines = [f"{res['images']} images of {res['folder']}; model {Path(res['model']).name}; "
             f"class map {', '.join(f'{a}->{b}' for a, b in res['class_map'].items())}", "",
             *_ap_header(small)]
    for n in res["scored_classes"]:
        lines.append(_ap_row(n, res["per_class"].get(n), res.get("per_class_24px", {}).get(n)))
    lines.append(f"| any (class-agnostic) | {res['any_ap50']:.3f} | | | "
                 f"{res['any_ap50_24px']:.3f} | | |")
    lines.append("")
    lines.append(f"**{res['vehicle_class']} AP50 {res['vehicle_ap50']:.3f}, boxes >= {small:g} "
                 f"px {res['vehicle_ap50_24px']:.3f}**; precision {res['precision']:.3f}, "
                 f"recall {res['recall']:.3f} at score >= {res['conf']:g}, IoU 0.5")
    return "\n".join(lines)


def format_table(res: dict) -> str:
    """A Markdown table: AP50 / AP50-95 / GT per class, all boxes and the size subset."""
    small = res.get("small_px", 24)
    lines = [f"{res['frames']} frames of {len(res['recordings'])} recordings; model "
             f"{Path(res['model']).name}", "", *_ap_header(small)]
    for n in res["class_counts"]:
        a = res["per_class"].get(n)
        b = res.get("per_class_24px", {}).get(n)
        if a is not None or b is not None:
            lines.append(_ap_row(n, a, b))
    lines.append(f"| **all** | **{res['map50']:.3f}** | **{res['map50_95']:.3f}** | {res['gt']} "
                 f"| **{res.get('map50_24px', float('nan')):.3f}** | "
                 f"**{res.get('map50_95_24px', float('nan')):.3f}** | {res.get('gt_24px', 0)} |")
    lines.append("")
    lines.append(f"precision {res['precision']:.3f}, recall {res['recall']:.3f} (all boxes); "
                 f"precision {res.get('precision_24px', float('nan')):.3f}, recall "
                 f"{res.get('recall_24px', float('nan')):.3f} (>= {small:g} px); at score >= "
                 f"{res['config']['conf']:g}, IoU 0.5")
    return "\n".join(lines)
