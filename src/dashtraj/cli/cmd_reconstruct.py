"""`dashtraj reconstruct` and `dashtraj bench-reconstruct`: routes from sightings."""

from __future__ import annotations

import argparse
import json

from dashtraj.cli._args import (
    MAX_OFF_ROAD_M,
    ArgumentError,
    non_negative_float,
    pose_sigma,
    positive_float,
    positive_int,
    seed,
)
from dashtraj.outputs import add_output_args

MAX_TURN_COST_M_PER_RAD = 1000.0
"""The largest ``--turn-cost``: a kilometre of route per radian of turning."""


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `reconstruct` and `bench-reconstruct` commands to the `dashtraj` parser.

    Args:
        subparsers: the object returned by `ArgumentParser.add_subparsers`.
    """
    p = subparsers.add_parser(
        "reconstruct",
        help="rebuild one vehicle's route from its sightings (CSV in, trajectory CSV out)",
        description=(
            "Rebuild the route one vehicle drove from its sightings on an OpenDRIVE map. "
            "Methods: 'hmm' (lane-level HMM map matching, default) and 'shortest-path' "
            "(the paper's lane correction + A*). Output: trajectory CSV x, y, t "
            "(CARLA world metres, seconds)."
        ),
    )
    p.add_argument("--map", required=True, metavar="MAP",
                   help="OpenDRIVE .xodr file, or a built-in town name")
    p.add_argument("--sightings", required=True, metavar="S.csv", help="sightings CSV")
    p.add_argument("--method", default="hmm", metavar="NAME",
                   help="reconstruction method: hmm (default) or shortest-path")
    p.add_argument("-o", "--output", required=True, metavar="T.csv", help="trajectory CSV to write")
    p.add_argument("--max-off-road", type=positive_float, default=MAX_OFF_ROAD_M, metavar="M",
                   help="drop sightings farther than M metres from every driving lane, with a "
                        "warning naming their lines; refuse a file where none is nearer "
                        f"(default {MAX_OFF_ROAD_M:g})")
    p.add_argument("--turn-cost", type=non_negative_float, default=None, metavar="M",
                   help="hmm: metres of route cost per radian of heading change, a prior "
                        "for routes with fewer turns (default 3; 0: by length alone)")
    p.add_argument("--pose-sigma", type=pose_sigma, default=None, metavar="XY_M,YAW_DEG",
                   help="hmm: the observers' own pose errors (a real drive's GNSS/INS: σ per "
                        "horizontal axis, metres; heading σ, degrees), added to the sightings' "
                        "error model (default: exact poses)")
    add_output_args(p)
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    p.set_defaults(func=run_reconstruct)

    b = subparsers.add_parser(
        "bench-reconstruct",
        help="score reconstruction methods on synthetic trips (SSPD, Hausdorff)",
        description=(
            "Make synthetic trips on a map (true routes, observers with dashcams, noisy "
            "sightings as in the paper), reconstruct each with every method and score "
            "it against the truth between its first and last sighting (SSPD and "
            "Hausdorff distance, metres)."
        ),
    )
    b.add_argument("--map", required=True, metavar="MAP",
                   help="OpenDRIVE .xodr file, or a built-in town name")
    b.add_argument("--trips", type=positive_int, default=50, metavar="N",
                   help="number of trips (50)")
    b.add_argument("--seed", type=seed, default=0, metavar="S", help="random seed (0)")
    b.add_argument("--methods", nargs="+", default=["shortest-path", "hmm"], metavar="NAME",
                   help="methods to compare (default: shortest-path hmm)")
    b.add_argument("--json", action="store_true",
                   help="print one JSON object (summary and per-trip rows) instead of a table")
    b.set_defaults(func=run_bench_reconstruct)


def _load_map(arg: str):
    """A RoadMap from an .xodr path, or from a built-in town name when no such file exists."""
    from dashtraj.cli._args import load_map

    return load_map(arg, "--map")


def _data_lines(path) -> list[int]:
    """The file line of each data row of a CSV (blank rows skipped, as the reader does)."""
    import csv

    lines: list[int] = []
    with open(path, newline="", encoding="utf-8-sig") as fh:
        reader = csv.reader(fh)
        header = False
        for row in reader:
            if not any(cell.strip() for cell in row):
                continue
            if header:
                lines.append(reader.line_num)
            header = True
    return lines


def drop_off_road(road_map, sightings, path, max_off_road_m: float):
    """The sightings within ``max_off_road_m`` of a driving lane; warns naming the others.

    Raises:
        InputFormatError: every sighting is off the map (wrong map or wrong frame).
    """
    import warnings

    import numpy as np

    from dashtraj.errors import InputFormatError

    xy = np.array([[s.x, s.y] for s in sightings], dtype=float)
    dist = road_map.project(xy).distance_m
    far = np.flatnonzero(dist > max_off_road_m)
    if len(far) == 0:
        return list(sightings)
    lines = _data_lines(path)
    where = ", ".join(f"line {lines[i]} ({xy[i, 0]:g}, {xy[i, 1]:g}) {dist[i]:.1f} m"
                      for i in far[:3]) + (f" and {len(far) - 3} more" if len(far) > 3 else "")
    if len(far) == len(sightings):
        raise InputFormatError(
            f"{path}: all {len(far)} sightings lie more than {max_off_road_m:g} m from every "
            f"driving lane of {road_map.name} ({where}); wrong map or frame? "
            f"(--max-off-road sets the limit)")
    warnings.warn(f"{path}: dropped {len(far)} of {len(sightings)} sightings more than "
                  f"{max_off_road_m:g} m from every driving lane of {road_map.name}: {where} "
                  f"(--max-off-road sets the limit)", stacklevel=2)
    keep = np.ones(len(sightings), dtype=bool)
    keep[far] = False
    return [s for s, k in zip(sightings, keep, strict=True) if k]


def run_reconstruct(args: argparse.Namespace) -> int:
    """Reconstruct one route, write it, print a one-line summary; return 0.

    Raises:
        DashtrajError: missing or malformed map / sightings, unknown method.

    Example:
        $ dashtraj reconstruct --map Town10HD.xodr --sightings s.csv -o t.csv
        hmm: 20 of 20 sightings used, 512 points, 498.3 m -> t.csv
    """
    from dashtraj.outputs import atomic_output, check_output
    from dashtraj.trajectory.io import read_sightings, write_trajectory
    from dashtraj.trajectory.reconstruct import METHODS, reconstruct

    check_output(args.output, overwrite=args.overwrite, kind="file")
    if args.method not in METHODS:
        raise ArgumentError(f"--method {args.method!r} is not a reconstruction method; "
                            f"valid: {', '.join(sorted(METHODS))}")
    options = {}
    if args.turn_cost is not None:
        if args.method != "hmm":
            raise ArgumentError("--turn-cost applies to --method hmm only")
        if args.turn_cost > MAX_TURN_COST_M_PER_RAD:
            raise ArgumentError(f"--turn-cost {args.turn_cost:g} m per radian is more than "
                                f"{MAX_TURN_COST_M_PER_RAD:g}: every turn would cost more than "
                                "any route, and the HMM would jump straight between sightings")
        options["turn_cost_m_per_rad"] = args.turn_cost
    if args.pose_sigma is not None:
        if args.method != "hmm":
            raise ArgumentError("--pose-sigma applies to --method hmm only")
        options["sigma_pose_m"], options["sigma_pose_deg"] = args.pose_sigma
    road_map = _load_map(args.map)
    read = read_sightings(args.sightings)
    sightings = drop_off_road(road_map, read, args.sightings, args.max_off_road)
    rec = reconstruct(road_map, sightings, method=args.method, **options)
    with atomic_output(args.output, overwrite=args.overwrite, kind="file") as tmp:
        write_trajectory(tmp, rec.trajectory)
    summary = {
        "method": rec.method,
        "sightings": len(read),
        "dropped_off_road": len(read) - len(sightings),
        "sightings_used": int(rec.details.get("sightings_used", len(rec.matched))),
        "points": len(rec.trajectory),
        "length_m": rec.trajectory.length_m,
        "output": str(args.output),
    }
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"{summary['method']}: {summary['sightings_used']} of {summary['sightings']} "
              f"sightings used"
              + (f" ({summary['dropped_off_road']} off the road, dropped)"
                 if summary["dropped_off_road"] else "")
              + f", {summary['points']} points, {summary['length_m']:.1f} m "
              f"-> {summary['output']}")
    return 0


def run_bench_reconstruct(args: argparse.Namespace) -> int:
    """Run the synthetic bench and print a table (or JSON); return 0.

    Raises:
        DashtrajError: bad map, unknown method, or a non-positive --trips.

    Example:
        $ dashtraj bench-reconstruct --map Town01.xodr --trips 5 --seed 0
    """
    from dashtraj.trajectory.synth import run_bench

    road_map = _load_map(args.map)
    res = run_bench(road_map, args.trips, seed=args.seed, methods=args.methods)
    if args.json:
        print(json.dumps(res))
        return 0
    print(f"{res['map']}: {res['trips']} trips, seed {res['seed']} (metres; truth between "
          f"first and last sighting)")
    head = (f"{'method':<14} {'SSPD mean':>10} {'SSPD med':>9} {'HD mean':>9} {'HD med':>8} "
            f"{'ms/trip':>8}")
    print(head)
    for name, s in res["methods"].items():
        print(f"{name:<14} {s['sspd_mean_m']:>10.2f} {s['sspd_median_m']:>9.2f} "
              f"{s['hausdorff_mean_m']:>9.2f} {s['hausdorff_median_m']:>8.2f} "
              f"{s['time_mean_ms']:>8.1f}")
    return 0
