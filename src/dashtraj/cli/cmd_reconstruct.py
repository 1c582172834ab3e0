"""`dashtraj reconstruct` and `dashtraj bench-reconstruct`: routes from sightings."""

from __future__ import annotations

import argparse
import json


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
    b.add_argument("--trips", type=int, default=50, metavar="N", help="number of trips (50)")
    b.add_argument("--seed", type=int, default=0, metavar="S", help="random seed (0)")
    b.add_argument("--methods", nargs="+", default=["shortest-path", "hmm"], metavar="NAME",
                   help="methods to compare (default: shortest-path hmm)")
    b.add_argument("--json", action="store_true",
                   help="print one JSON object (summary and per-trip rows) instead of a table")
    b.set_defaults(func=run_bench_reconstruct)


def _load_map(arg: str):
    """A RoadMap from an .xodr path, or from a built-in town name when no such file exists."""
    from dashtraj.errors import DashtrajError, InputFormatError
    from dashtraj.roads import RoadMap
    from dashtraj.world.towns import resolve_map

    try:
        path = resolve_map(arg)
    except DashtrajError as exc:
        raise InputFormatError(f"--map {arg!r}: neither a file nor a built-in town ({exc})") \
            from None
    return RoadMap.from_file(path)


def run_reconstruct(args: argparse.Namespace) -> int:
    """Reconstruct one route, write it, print a one-line summary; return 0.

    Raises:
        DashtrajError: missing or malformed map / sightings, unknown method.

    Example:
        $ dashtraj reconstruct --map Town10HD.xodr --sightings s.csv -o t.csv
        hmm: 20 of 20 sightings used, 512 points, 498.3 m -> t.csv
    """
    from dashtraj.trajectory.io import read_sightings, write_trajectory
    from dashtraj.trajectory.reconstruct import reconstruct

    road_map = _load_map(args.map)
    sightings = read_sightings(args.sightings)
    rec = reconstruct(road_map, sightings, method=args.method)
    write_trajectory(args.output, rec.trajectory)
    summary = {
        "method": rec.method,
        "sightings": len(sightings),
        "sightings_used": int(rec.details.get("sightings_used", len(rec.matched))),
        "points": len(rec.trajectory),
        "length_m": rec.trajectory.length_m,
        "output": str(args.output),
    }
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"{summary['method']}: {summary['sightings_used']} of {summary['sightings']} "
              f"sightings used, {summary['points']} points, {summary['length_m']:.1f} m "
              f"-> {summary['output']}")
    return 0


def run_bench_reconstruct(args: argparse.Namespace) -> int:
    """Run the synthetic bench and print a table (or JSON); return 0.

    Raises:
        DashtrajError: bad map, unknown method, or a non-positive --trips.

    Example:
        $ dashtraj bench-reconstruct --map Town01.xodr --trips 5 --seed 0
    """
    from dashtraj.errors import InputFormatError
    from dashtraj.trajectory.synth import run_bench

    if args.trips < 1:
        raise InputFormatError(f"--trips must be at least 1, got {args.trips}")
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
