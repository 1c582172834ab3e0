"""`dashtraj simulate` (traffic → recording) and `dashtraj sightings` (recording → CSV)."""

from __future__ import annotations

import argparse
import json
import sys


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `simulate` and `sightings` commands to the `dashtraj` parser."""
    p = subparsers.add_parser(
        "simulate",
        help="simulate traffic with dashcam observers and write a recording directory",
        description=(
            "Drive a target, observers with dashcams and agents on a town's lanes (IDM car "
            "following, junction reservations) and write a recording: meta.json, "
            "vehicles.csv, states.parquet, truth.parquet, target_route.csv, map.xodr."
        ),
    )
    p.add_argument("--town", default="town01", metavar="NAME|PATH.xodr",
                   help="built-in town (town01, town10) or an OpenDRIVE file (default town01)")
    p.add_argument("--observers", type=int, default=4, help="observer cars (default 4)")
    p.add_argument("--agents", type=int, default=20, help="other cars (default 20)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--identities", type=_id_range, metavar="LO-HI",
                   help="draw vehicle identities with LO <= identity_id < HI only (e.g. "
                   "650-700, the ReID set's test identities)")
    p.add_argument("--vehicle-classes", type=_classes, default=None, metavar="C,C,...",
                   help="vehicle classes to draw (default car,truck,bus,motorcycle; also "
                   "bicycle)")
    p.add_argument("--vehicle-mix", choices=("catalog", "balanced"), default="catalog",
                   help="catalog: identities uniformly from the catalog (mostly cars); "
                   "balanced: an equal share of vehicles per class (default catalog)")
    p.add_argument("--duration", type=float, default=180.0, metavar="S",
                   help="simulated seconds (default 180; the most with --until-target-arrives)")
    p.add_argument("--until-target-arrives", action="store_true",
                   help="stop when the target reaches its destination")
    p.add_argument("--step", type=float, default=0.05, metavar="S",
                   help="simulation step, seconds (default 0.05 = 20 Hz)")
    p.add_argument("--observer-placement", choices=("meet", "random"), default="meet",
                   help="meet: observers start where the target will pass (oncoming, "
                        "following, waiting at a crossing); random: anywhere (default meet)")
    p.add_argument("--parked-fraction", type=_fraction, default=0.25, metavar="F",
                   help="share of the observers that are parked at the roadside for the whole "
                        "run, dashcam on (random placement: the last round(F * observers); "
                        "meet placement: F > 0 adds a 'parked' role to the cycle oncoming, "
                        "crossing, following, parked; 0: none) (default 0.25)")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="recording directory")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=run_simulate)

    s = subparsers.add_parser(
        "sightings",
        help="turn a recording's ground truth into a sightings CSV (oracle detector)",
        description=(
            "Oracle sightings of one vehicle from a recording: truth within --max-distance "
            "of a camera, one per observer track every 0.5 s, with no noise or the paper's "
            "localization errors; positions from camera pose + distance along "
            "(yaw + signed bearing)."
        ),
    )
    s.add_argument("recording", metavar="RUN", help="recording directory")
    s.add_argument("--oracle", action="store_true", required=True,
                   help="use the ground truth as a perfect detector (the only source for now)")
    s.add_argument("--noise", default="none", help="none or paper (default none)")
    s.add_argument("--vehicle", default="target", metavar="ID|target",
                   help="vehicle to report (default: the target)")
    s.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    s.add_argument("--max-distance", type=float, default=15.0, metavar="M",
                   help="keep detections this close to the camera, metres (default 15)")
    s.add_argument("-o", "--output", required=True, metavar="CSV", help="sightings CSV to write")
    s.set_defaults(func=run_sightings)


def _fraction(text: str) -> float:
    try:
        f = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}") from None
    if not 0.0 <= f <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}")
    return f


def _classes(text: str) -> tuple[str, ...]:
    from dashtraj.world.catalog import VEHICLE_CLASSES

    out = tuple(c.strip() for c in text.split(",") if c.strip())
    bad = [c for c in out if c not in VEHICLE_CLASSES]
    if not out or bad:
        raise argparse.ArgumentTypeError(f"unknown vehicle class(es) {bad or text!r}; valid: "
                                         f"{', '.join(VEHICLE_CLASSES)}")
    return out


def _id_range(text: str) -> tuple[int, int]:
    try:
        lo, hi = (int(v) for v in text.split("-"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LO-HI, got {text!r}") from None
    if not 0 <= lo < hi:
        raise argparse.ArgumentTypeError(f"expected 0 <= LO < HI, got {text!r}")
    return lo, hi


def run_simulate(args: argparse.Namespace) -> int:
    """Run the simulation, print a summary; returns 0 (130 is handled by the caller)."""
    from dataclasses import replace

    from dashtraj.world.recording import RunConfig, simulate
    from dashtraj.world.traffic import TrafficConfig

    config = RunConfig(map=args.town, seed=args.seed, duration_s=args.duration,
                       n_observers=args.observers, n_agents=args.agents,
                       until_target_arrives=args.until_target_arrives,
                       identity_range=args.identities, vehicle_mix=args.vehicle_mix,
                       **({"vehicle_classes": args.vehicle_classes}
                          if args.vehicle_classes else {}),
                       traffic=replace(TrafficConfig(), step_s=args.step,
                                       observer_placement=args.observer_placement,
                                       parked_fraction=args.parked_fraction))
    bar = None
    progress = None
    if not args.quiet and sys.stderr.isatty():
        from tqdm import tqdm

        bar = tqdm(total=args.duration, unit="sim s", file=sys.stderr,
                   bar_format="{l_bar}{bar}| {n:.1f}/{total:.0f} s [{elapsed}<{remaining}]")

        def progress(t: float) -> None:
            bar.n = t
            if round(t / config.traffic.step_s) % 20 == 0:
                bar.refresh()
    try:
        summary = simulate(config, args.output, progress=progress)
    finally:
        if bar is not None:
            bar.close()
    info = {"recording": str(summary.path), "vehicles": summary.vehicles,
            "frames": summary.frames, "truth_rows": summary.truth_rows,
            "simulated_s": summary.simulated_to_t,
            "target_arrived_t": summary.target_arrived_t, "complete": summary.complete}
    if args.json:
        print(json.dumps(info))
    else:
        arrived = (f"target arrived at t={summary.target_arrived_t:.1f} s"
                   if summary.target_arrived_t is not None else "target did not arrive")
        print(f"{summary.path}: {summary.vehicles} vehicles, {summary.frames} frames "
              f"({summary.simulated_to_t:.1f} s), {summary.truth_rows} truth rows; {arrived}")
    return 0


def run_sightings(args: argparse.Namespace) -> int:
    """Write oracle sightings of one vehicle to a CSV and print how many; returns 0."""
    from dashtraj.trajectory.io import write_sightings
    from dashtraj.world.oracle import OracleConfig, oracle_sightings
    from dashtraj.world.recording import Recording

    rec = Recording.open(args.recording)
    cfg = OracleConfig(vehicle=args.vehicle, max_distance_m=args.max_distance, noise=args.noise,
                       seed=args.seed)
    sightings = oracle_sightings(rec, cfg)
    write_sightings(args.output, sightings)
    observers = len({s.observer_id for s in sightings})
    tracks = len({s.track_id for s in sightings})
    if not sightings:
        print(f"dashtraj: warning: no sightings of vehicle {args.vehicle} within "
              f"{args.max_distance:g} m of a camera; {args.output} has only its header",
              file=sys.stderr)
    print(f"{args.output}: {len(sightings)} sightings of vehicle {args.vehicle} by "
          f"{observers} observers in {tracks} tracks (noise {args.noise})")
    return 0
