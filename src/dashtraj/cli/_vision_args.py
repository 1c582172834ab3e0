"""The options of `demo` and `experiments` for sightings from pixels (``--sightings vision``),
checked at the boundary before any simulation starts."""

from __future__ import annotations

import argparse
from pathlib import Path

from dashtraj.cli._args import (
    ArgumentError,
    add_detector_filter_args,
    add_pose_noise_args,
    image_size,
    int_at_least,
    positive_float,
    require_file,
)
from dashtraj.cli.cmd_detect import add_classifier_arg, classifier_path_from_arg

VISION_SIZE = (640, 360)
"""Default image size of ``--sightings vision``, pixels (the shipped detector's training
frames; its input is 640 × 384)."""

VISION_EVERY_S = 0.2
"""Default frame period of ``--sightings vision``, seconds: the detector runs on every
second frame of the 10 Hz dashcam (5 frames/s; the sightings are sampled every 0.5 s).
Half the perception cost of 0.1 s; the README's "From pixels, fast" section measures
what it costs in recall."""

DETECTIONS_EVERY_S = 0.1
"""Default frame period of ``--sightings detections``, seconds."""

VISION_ROUTE_M = 20.0
"""Default ``--route-range`` of ``--sightings vision``, metres (or the gallery's range where
that is farther): the accepted tracks' detections out to 20 m join the route's sightings,
and the box relations see the tracks out to 20 m (`target_from_db`'s ``route_m``). Chosen
on the development seeds 5-9 over 30 m (the README's "The accepted tracks' farther
sightings"); ``--route-range 15`` (the gallery's range) turns it off."""


def add_vision_args(p: argparse.ArgumentParser, default_sightings: str | None = "oracle") -> None:
    """The vision options; `default_sightings` None leaves ``--sightings`` None for the
    command to resolve."""
    p.add_argument("--sightings", choices=("oracle", "detections", "vision"),
                   default=default_sightings,
                   help="the target's sightings: from pixels with appearance ReID (vision, "
                        "the default); the oracle with --noise; or the camera pipeline "
                        "with the target's tracks picked by true identity (detections)")
    p.add_argument("--detector", default="shipped", metavar="shipped|gpu|oracle|M.onnx",
                   help="vision: the detector (default shipped: the package's ONNX model; "
                        "gpu: the package's model trained on GPU renders, better on real "
                        "CARLA frames; oracle: the renderer's exact boxes)")
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
    p.add_argument("--every", type=positive_float, default=None, metavar="S",
                   help=f"detections/vision: frame period, seconds (default: vision "
                        f"{VISION_EVERY_S:g} = {1 / VISION_EVERY_S:g} frames/s, detections "
                        f"{DETECTIONS_EVERY_S:g})")
    p.add_argument("--workers", type=int_at_least(1), default=2, metavar="N",
                   help="detections/vision: perception processes, observers in parallel "
                        "(default 2: the two cores of the reference machine)")
    p.add_argument("--localizer", default="smoothed", metavar="NAME",
                   help="detections/vision: perceive's localizer (paper, ground, fused, "
                        "tracked, smoothed or mapped; default smoothed)")
    p.add_argument("--live-relink", action="store_true",
                   help="detections/vision: perceive re-links ego's tracks by appearance as "
                        "the frames come (dashtraj perceive --live-relink; the ReID model "
                        "is --reid-model's)")
    add_range_args(p, "the query's 15 m", scope="vision: ")
    add_watch_arg(p, scope="vision: ")
    add_lookalike_arg(p, scope="vision: ")
    add_classifier_arg(p, scope="vision: ")
    add_detector_filter_args(p)
    add_pose_noise_args(p, with_seed=False)


def add_range_args(p: argparse.ArgumentParser, query: str, scope: str = "") -> None:
    """``--gallery-range`` and ``--route-range`` (`target_from_db`'s ``gallery_m`` and
    ``route_m``; `route_range` resolves the latter's default); ``query`` names the query's
    range in their help, ``scope`` starts it."""
    p.add_argument("--gallery-range", type=positive_float, default=None, metavar="M",
                   help=f"{scope}the gallery and the target's sightings are the detections "
                        f"estimated within M metres, at least {query} (default: {query}); "
                        f"the query stays the first crop within that")
    p.add_argument("--route-range", type=positive_float, default=None, metavar="M",
                   help=f"{scope}the accepted tracks' detections out to M metres join the "
                        f"target's sightings that the route is rebuilt from, and a camera's "
                        f"tracks seen at once within M metres are two vehicles; at least the "
                        f"gallery's range (default {VISION_ROUTE_M:g}, or the gallery's range "
                        f"where farther; the gallery's range turns it off)")


def add_watch_arg(p: argparse.ArgumentParser, scope: str = "") -> None:
    """``--watch`` / ``--no-watch``: negative evidence in the gate (`target_from_db`'s
    ``watch``; None: the library's default, `dashtraj.reidentify.vision.WATCH`)."""
    p.add_argument("--watch", action=argparse.BooleanOptionalAction, default=None,
                   help=f"{scope}the gate also splits two tracks when every way one car could "
                        f"have driven between them led through places the cameras watched and "
                        f"saw empty (negative evidence; default: "
                        f"dashtraj.reidentify.vision.WATCH, off)")


def add_lookalike_arg(p: argparse.ArgumentParser, scope: str = "") -> None:
    """``--lookalike`` / ``--no-lookalike``: `target_from_db`'s ``lookalike`` (None: the
    library's default, `dashtraj.reidentify.vision.LOOKALIKE`)."""
    p.add_argument("--lookalike", action=argparse.BooleanOptionalAction, default=None,
                   help=f"{scope}once the gate has dropped a candidate that looks like the "
                        f"target, keep only the tracks linked to the query's by unseen "
                        f"stretches of at most 30 s (default: "
                        f"dashtraj.reidentify.vision.LOOKALIKE, off)")


def vision_settings(args) -> dict:
    """ExperimentConfig keyword arguments of the vision options, checked (one line naming
    the argument, exit 2, on a bad value)."""
    from dashtraj.perception.detect import SHIPPED_DETECTORS
    from dashtraj.render.look import PRESETS

    names = (*SHIPPED_DETECTORS, "oracle")
    if args.detector not in names:
        p = Path(args.detector)
        if p.suffix.lower() != ".onnx" or not p.is_file():
            raise ArgumentError(f"--detector {args.detector!r}: expected {', '.join(names)} "
                                "or an existing .onnx file")
    require_file("--reid-model", args.reid_model)
    require_file("--reid-threshold", args.reid_threshold)
    if args.look is not None and args.look not in PRESETS:
        raise ArgumentError(f"--look {args.look!r}: unknown preset; valid: "
                            f"{', '.join(sorted(PRESETS))}")
    from dashtraj.perception.localize import LOCALIZERS

    if args.localizer not in LOCALIZERS:
        raise ArgumentError(f"--localizer {args.localizer!r}: valid: {', '.join(LOCALIZERS)}")
    size = None
    if args.size is not None:
        w, h = (int(v) for v in args.size.lower().split("x"))
        size = (w, h)
    elif args.sightings == "vision":
        size = VISION_SIZE
    every = args.every if args.every is not None else (
        VISION_EVERY_S if args.sightings == "vision" else DETECTIONS_EVERY_S)
    return {"sightings": args.sightings, "detector": args.detector,
            "reid_model": args.reid_model, "reid_threshold": args.reid_threshold,
            "look": args.look, "image_size": size, "every_s": every, "workers": args.workers,
            "agnostic_nms_iou": args.agnostic_nms, "min_score": args.min_score,
            "classifier": classifier_path_from_arg(args.classifier),
            "confirm_score": args.confirm_score, "localizer": args.localizer,
            "pose_noise": args.pose_noise, "calibrate_pitch": args.calibrate_pitch,
            "live_relink": args.live_relink, "gallery_m": args.gallery_range,
            "watch": args.watch, "lookalike": args.lookalike,
            "route_m": (route_range(args.route_range, args.gallery_range)
                        if args.sightings == "vision" else args.route_range)}


def route_range(given: float | None, gallery_m: float | None,
                query_m: float = 15.0) -> float:
    """``--route-range``: the one given, or its default, `VISION_ROUTE_M` or the gallery's
    range (``gallery_m``, else the query's ``query_m``) where that is farther, metres."""
    if given is not None:
        return given
    return max(VISION_ROUTE_M, gallery_m if gallery_m is not None else query_m)


def check_reid_model(config) -> None:
    """Load the ReID model and its threshold once, before hours of work (vision with
    appearance ReID); a missing or stale threshold is one line."""
    if config.sightings == "vision" and config.reid == "appearance":
        from dashtraj.experiments import reid_model_of

        reid_model_of(config)
