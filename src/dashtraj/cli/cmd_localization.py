"""`dashtraj localization eval|calibrate`: localizer errors against the truth; Eq. 3's
constant fitted the paper's way."""

from __future__ import annotations

import argparse
import json


def register(subparsers: argparse._SubParsersAction) -> None:
    from dashtraj.cli._args import (
        add_frame_source_args,
        add_pose_noise_args,
        picture_path,
        positive_float,
        positive_int,
        seed,
    )
    from dashtraj.outputs import add_output_args

    p = subparsers.add_parser(
        "localization", help="evaluate the localizers; calibrate Eq. 3's sensor constant")
    sub = p.add_subparsers(dest="localization_command", metavar="SUBCOMMAND")
    sub.required = True
    e = sub.add_parser(
        "eval", help="position and distance errors per estimator, < 20 m and 20–60 m",
        description=(
            "Localize the detections of every observer's frames with each estimator and "
            "compare with the true vehicle centres: position RMSE and median, distance RMSE, "
            "in the bands < 20 m and 20–60 m of true distance; a scatter plot of estimated vs "
            "true distance with --plot."),
    )
    add_frame_source_args(e, every_s=0.5)
    add_pose_noise_args(e)
    e.add_argument("--localizers", nargs="+", metavar="NAME",
                   default=["paper", "ground", "fused", "tracked", "smoothed", "mapped"],
                   help="estimators (default all: paper ground fused tracked smoothed mapped)")
    e.add_argument("--track-every", type=positive_float, default=0.1, metavar="S",
                   help="frame period fed to the sequential estimators (tracked, smoothed), scored "
                        "every --every seconds like the others (default 0.1, perceive's)")
    e.add_argument("--mu-h", type=positive_float, metavar="PX",
                   help="Eq. 3's constant (default ours)")
    e.add_argument("--plot", type=picture_path, metavar="PNG", help="write the scatter plot here")
    e.add_argument("--json", action="store_true", help="print the result as JSON")
    add_output_args(e)
    e.set_defaults(func=run_eval)

    c = sub.add_parser(
        "calibrate", help="fit Eq. 3's sensor constant from N known distances (paper: 51)",
        description=(
            "The paper's calibration of Eq. 3: μ_h = mean over N detections of "
            "H_class f I_H / (D_true h_px), the detections drawn at random (seeded) from the "
            "recordings' oracle boxes."),
    )
    c.add_argument("recordings", nargs="+", metavar="RUN")
    c.add_argument("-n", type=positive_int, default=51, help="known distances used (default 51)")
    c.add_argument("--seed", type=seed, default=0)
    c.add_argument("--every", type=positive_float, default=0.5, metavar="S")
    c.add_argument("--max-distance", type=positive_float, default=60.0, metavar="M")
    c.add_argument("--json", action="store_true")
    c.set_defaults(func=run_calibrate)


def _size(text):
    if not text:
        return None
    from dashtraj.datasets.frames import parse_size

    return parse_size(text)


def run_eval(args: argparse.Namespace) -> int:
    from dashtraj.cli._args import detector_filters_used
    from dashtraj.outputs import atomic_output, check_output
    from dashtraj.perception.evaluate import localization_eval, open_recording, scatter_png
    from dashtraj.perception.localize import build_localizer

    for n in args.localizers:
        build_localizer(n)
    if args.plot:
        check_output(args.plot, overwrite=args.overwrite, kind="file")
    recs = [open_recording(r) for r in args.recordings]
    summary, samples = localization_eval(recs, args.localizers, args.detector, args.every,
                                         _size(args.size), args.mu_h, args.track_every,
                                         args.agnostic_nms, args.min_score,
                                         pose_noise=args.pose_noise,
                                         pose_noise_seed=args.pose_noise_seed,
                                         calibrate_pitch=args.calibrate_pitch)
    if args.plot:
        with atomic_output(args.plot, overwrite=args.overwrite, kind="file") as tmp:
            scatter_png(samples, args.localizers, tmp)
    out = {"detector": args.detector, **detector_filters_used(args),
           "pose_noise": None if args.pose_noise is None else list(args.pose_noise),
           "calibrate_pitch": args.calibrate_pitch,
           "detections": len(samples["true_m"]), **summary}
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"{out['detections']} detections of {len(recs)} recordings (detector {args.detector})")

    def f(v):
        return "  n/a" if v is None else f"{v:5.2f}"

    def line(n, r):
        print(f"  {n:8s} position RMSE < 20 m {f(r['rmse_lt20_m'])} m (median "
              f"{f(r['median_lt20_m'])}), 20–60 m {f(r['rmse_20_60_m'])} m (median "
              f"{f(r['median_20_60_m'])})")

    for n in args.localizers:
        line(n, summary[n])
    print("ignore regions (the detector protocol's: vehicles under 20 px high at 1280 x 720 "
          "or over 70 % hidden are not scored):")
    for n in args.localizers:
        line(n, summary[n]["ignore_regions"])
    return 0


def run_calibrate(args: argparse.Namespace) -> int:
    import numpy as np

    from dashtraj.errors import DashtrajError
    from dashtraj.perception.evaluate import eval_frames, open_recording, truth_positions
    from dashtraj.perception.localize import calibrate_paper_constant
    from dashtraj.perception.pipeline import image_camera

    boxes, cls, dist, spec = [], [], [], None
    for path in args.recordings:
        rec = open_recording(path)
        spec = image_camera(rec, None)
        where = truth_positions(rec)
        for ef in eval_frames(rec, "oracle", args.every):
            d = ef.detections
            if not len(d):
                continue
            x, y = where(ef, d.truth_ids)
            td = np.hypot(x - ef.pose.x, y - ef.pose.y)
            ok = (td <= args.max_distance) & (d.boxes[:, 1] > 1) & \
                 (d.boxes[:, 3] < spec.height_px - 1)
            boxes.append(d.boxes[ok])
            cls.append(d.class_ids[ok])
            dist.append(td[ok])
    n_found = sum(len(t) for t in dist)
    if n_found < args.n:
        raise DashtrajError(f"only {n_found} detections within {args.max_distance:g} m; "
                            f"-n {args.n} needs more")
    b, c, td = np.concatenate(boxes), np.concatenate(cls), np.concatenate(dist)
    pick = np.random.default_rng(args.seed).choice(len(td), args.n, replace=False)
    mu = calibrate_paper_constant(spec, b[pick], c[pick], td[pick])
    scaled = mu * 720.0 / spec.height_px
    out = {"mu_h": mu, "mu_h_at_720": scaled, "n": args.n, "height_px": spec.height_px}
    if args.json:
        print(json.dumps(out))
    else:
        print(f"Eq. 3 sensor constant μ_h = {mu:.2f} px from {args.n} known distances "
              f"({spec.width_px}x{spec.height_px}; {scaled:.2f} at 720 px high; the paper: "
              "599.46)")
    return 0
