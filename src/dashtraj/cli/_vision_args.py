"""The options of `demo` and `experiments` for sightings from pixels (``--sightings vision``),
checked at the boundary before any simulation starts."""

from __future__ import annotations

import argparse
from pathlib import Path

from dashtraj.cli._args import ArgumentError, image_size, positive_float

VISION_SIZE = (640, 360)
"""Default image size of ``--sightings vision``, pixels (the shipped detector's training
frames; its input is 640 × 384)."""


def add_vision_args(p: argparse.ArgumentParser, default_sightings: str = "oracle") -> None:
    p.add_argument("--sightings", choices=("oracle", "detections", "vision"),
                   default=default_sightings,
                   help="the target's sightings: the oracle with --noise; the camera pipeline "
                        "with the target's tracks picked by true identity (detections); or from "
                        "pixels with appearance ReID (vision)")
    p.add_argument("--detector", default="shipped", metavar="shipped|oracle|M.onnx",
                   help="vision: the detector (default shipped: the package's ONNX model; "
                        "oracle: the renderer's exact boxes)")
    p.add_argument("--reid-model", default=None, metavar="M.onnx",
                   help="vision: the ReID model (default: the shipped one)")
    p.add_argument("--reid-threshold", default=None, metavar="FILE",
                   help="vision: the model's calibrated threshold JSON (default: "
                        "M.threshold.json beside the model; `dashtraj reid-threshold`)")
    p.add_argument("--look", default=None, metavar="PRESET",
                   help="vision: render look preset (default: the look the threshold was "
                        "calibrated on, i.e. the models' domain)")
    p.add_argument("--size", type=image_size, default=None, metavar="WxH",
                   help="detections/vision: image size (vision default 640x360)")
    p.add_argument("--every", type=positive_float, default=0.1, metavar="S",
                   help="detections/vision: frame period, seconds (default 0.1 = 10 fps)")


def vision_settings(args) -> dict:
    """ExperimentConfig keyword arguments of the vision options, checked (one line naming
    the argument, exit 2, on a bad value)."""
    from dashtraj.render.look import PRESETS

    if args.detector not in ("shipped", "oracle"):
        p = Path(args.detector)
        if p.suffix.lower() != ".onnx" or not p.is_file():
            raise ArgumentError(f"--detector {args.detector!r}: expected shipped, oracle or an "
                                "existing .onnx file")
    if args.reid_model is not None and not Path(args.reid_model).is_file():
        raise ArgumentError(f"--reid-model {args.reid_model!r}: no such file")
    if args.reid_threshold is not None and not Path(args.reid_threshold).is_file():
        raise ArgumentError(f"--reid-threshold {args.reid_threshold!r}: no such file")
    if args.look is not None and args.look not in PRESETS:
        raise ArgumentError(f"--look {args.look!r}: unknown preset; valid: "
                            f"{', '.join(sorted(PRESETS))}")
    size = None
    if args.size is not None:
        w, h = (int(v) for v in args.size.lower().split("x"))
        size = (w, h)
    elif args.sightings == "vision":
        size = VISION_SIZE
    return {"sightings": args.sightings, "detector": args.detector,
            "reid_model": args.reid_model, "reid_threshold": args.reid_threshold,
            "look": args.look, "image_size": size, "every_s": args.every}


def check_reid_model(config) -> None:
    """Load the ReID model and its threshold once, before hours of work (vision with
    appearance ReID); a missing or stale threshold is one line."""
    if config.sightings == "vision" and config.reid == "appearance":
        from dashtraj.experiments import reid_model_of

        reid_model_of(config)
