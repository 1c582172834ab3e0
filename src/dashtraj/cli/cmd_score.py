"""`dashtraj score`: SSPD and Hausdorff distance of an estimated route against the truth."""

from __future__ import annotations

import argparse
import json

MAX_RESAMPLED_POINTS = 200_000
"""The most points ``--resample-m`` may make of one trajectory (SSPD compares every
point with every segment of the other trajectory)."""


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `score` command to the `dashtraj` parser.

    Args:
        subparsers: the object returned by `ArgumentParser.add_subparsers`.
    """
    p = subparsers.add_parser(
        "score",
        help="SSPD and Hausdorff distance (metres) between two trajectory CSVs",
        description=(
            "Score an estimated trajectory against the true one with SSPD and Hausdorff "
            "distance, as traj-dist computes them (vertex-to-segment, Euclidean, CARLA "
            "world metres). Trajectory CSVs have columns x, y and optionally t."
        ),
    )
    p.add_argument("--truth", required=True, metavar="A.csv", help="true trajectory CSV")
    p.add_argument("--estimate", required=True, metavar="B.csv", help="estimated trajectory CSV")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    p.add_argument(
        "--resample-m",
        type=float,
        default=None,
        metavar="M",
        help="resample both trajectories every M metres of arc length first "
        "(default: use the points as given, like the paper)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Read both trajectories, print their SSPD and Hausdorff distance, return 0.

    Args:
        args: parsed arguments with `truth`, `estimate`, `json`, `resample_m`.

    Returns:
        0 on success.

    Raises:
        DashtrajError: an input file is missing or malformed (InputFormatError),
            or `--resample-m` is not positive.

    Example:
        $ dashtraj score --truth truth.csv --estimate est.csv
        SSPD 1.234 m  Hausdorff 5.678 m  (truth 120 points, estimate 98 points)
    """
    from dashtraj.errors import InputFormatError
    from dashtraj.trajectory.io import read_trajectory
    from dashtraj.trajectory.metrics import hausdorff, sspd

    if args.resample_m is not None and not 0 < args.resample_m < float("inf"):
        raise InputFormatError(
            f"--resample-m must be a positive number of metres, got {args.resample_m}"
        )
    truth = read_trajectory(args.truth)
    estimate = read_trajectory(args.estimate)
    if args.resample_m is not None:
        for name, traj in (("--truth", truth), ("--estimate", estimate)):
            n = traj.length_m / args.resample_m
            if n > MAX_RESAMPLED_POINTS:
                raise InputFormatError(
                    f"--resample-m {args.resample_m:g}: {name} would become {n:.3g} points "
                    f"(at most {MAX_RESAMPLED_POINTS:,}); choose a coarser step")
    sspd_m = sspd(truth, estimate, resample_m=args.resample_m)
    hausdorff_m = hausdorff(truth, estimate, resample_m=args.resample_m)
    if args.json:
        print(
            json.dumps(
                {
                    "sspd_m": sspd_m,
                    "hausdorff_m": hausdorff_m,
                    "truth_points": len(truth),
                    "estimate_points": len(estimate),
                }
            )
        )
    else:
        print(
            f"SSPD {sspd_m:.3f} m  Hausdorff {hausdorff_m:.3f} m  "
            f"(truth {len(truth)} points, estimate {len(estimate)} points)"
        )
    return 0
