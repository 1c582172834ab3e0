"""`dashtraj simulate` (traffic → recording) and `dashtraj sightings` (recording → CSV)."""

from __future__ import annotations

import argparse
import json
import sys

from dashtraj.cli._args import count, duration, fraction, non_negative_float, positive_float, seed
from dashtraj.outputs import add_output_args


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
    p.add_argument("--observers", type=count, default=4, help="observer cars (default 4)")
    p.add_argument("--agents", type=count, default=20,
                   help="other cars (default 20; a town holds about one vehicle per 20 m of "
                        "lane, e.g. town01 about 230)")
    p.add_argument("--twins", type=count, default=0, metavar="N",
                   help="N more agents of the target's exact model and colour (look-alikes "
                        "for re-identification; default 0)")
    p.add_argument("--seed", type=seed, default=0, help="random seed (default 0)")
    p.add_argument("--identities", type=_id_range, metavar="LO-HI",
                   help="draw vehicle identities with LO <= identity_id < HI only (e.g. "
                   "650-700, the ReID set's test identities)")
    p.add_argument("--vehicle-classes", type=_classes, default=None, metavar="C,C,...",
                   help="vehicle classes to draw (default car,truck,bus,motorcycle; also "
                   "bicycle)")
    p.add_argument("--vehicle-mix", choices=("catalog", "balanced"), default="catalog",
                   help="catalog: identities uniformly from the catalog (mostly cars); "
                   "balanced: an equal share of vehicles per class (default catalog)")
    p.add_argument("--duration", type=duration, default=180.0, metavar="S",
                   help="the longest simulated time, seconds (default 180)")
    p.add_argument("--until-target-arrives", action=argparse.BooleanOptionalAction,
                   default=True,
                   help="stop when the target reaches its destination (default); with "
                        "--no-until-target-arrives the others drive on to --duration "
                        "(target_route.csv still ends at the target's arrival)")
    p.add_argument("--step", type=positive_float, default=0.05, metavar="S",
                   help="simulation step, seconds (default 0.05 = 20 Hz)")
    p.add_argument("--observer-placement", choices=("meet", "random"), default="meet",
                   help="meet: observers start where the target will pass (oncoming, "
                        "following, waiting at a crossing); random: anywhere (default meet)")
    p.add_argument("--parked-fraction", type=fraction, default=0.25, metavar="F",
                   help="share of the observers that are parked at the roadside for the whole "
                        "run, dashcam on (random placement: the last round(F * observers); "
                        "meet placement: F > 0 adds a 'parked' role to the cycle oncoming, "
                        "crossing, following, parked; 0: none) (default 0.25)")
    p.add_argument("-o", "--output", required=True, metavar="DIR",
                   help="recording directory (a new one; an interrupted run is kept as "
                        "DIR.partial-N, marked incomplete)")
    add_output_args(p)
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=run_simulate)

    s = subparsers.add_parser(
        "sightings",
        help="sightings CSV from a recording (oracle or camera pipeline) or a sightings DB",
        description=(
            "Sightings of one vehicle from a recording. Source 'oracle' (the default): the "
            "truth within --max-distance of a camera, one per observer track every 0.5 s, with "
            "no noise or the paper's localization errors; positions from camera pose + distance "
            "along (yaw + signed bearing). With --detector oracle|M.onnx: the camera pipeline "
            "(dashtraj perceive: render, detect, track, localize) and the detections that the "
            "truth assigns to the vehicle. 'dashtraj sightings export DB -o S.csv' writes a "
            "sightings database (dashtraj perceive) as the same CSV."
        ),
    )
    s.add_argument("recording", metavar="RUN", help="recording directory, or 'export'")
    s.add_argument("db", nargs="?", metavar="DB",
                   help="with 'export': the sightings database (dashtraj perceive -o DB)")
    s.add_argument("--oracle", action="store_true",
                   help="the ground truth as a perfect detector and localizer (the default "
                        "source; the flag is kept for old scripts)")
    s.add_argument("--detector", metavar="oracle|M.onnx",
                   help="run the camera pipeline with this detector instead (see perceive)")
    s.add_argument("--tracker", choices=("sort", "ego"), default=None,
                   help="with --detector: the tracker (default ego)")
    s.add_argument("--localizer", default=None,
                   help="with --detector: paper, ground, fused, tracked, smoothed or mapped "
                        "(default smoothed)")
    s.add_argument("--noise", choices=("none", "paper"), default="none",
                   help="oracle localization noise: none or paper (default none)")
    s.add_argument("--vehicle", default="target", metavar="ID|target|all",
                   help="vehicle to report (default: the target; 'all' with export)")
    s.add_argument("--seed", type=seed, default=0, help="noise seed (default 0)")
    s.add_argument("--max-distance", type=positive_float, default=15.0, metavar="M",
                   help="keep detections this close to the camera, metres (default 15)")
    s.add_argument("--sample", type=non_negative_float, default=None, metavar="S",
                   help="detections/export: one sighting per track every S seconds (default 0.5)")
    s.add_argument("-o", "--output", required=True, metavar="CSV", help="sightings CSV to write")
    add_output_args(s)
    s.set_defaults(func=run_sightings)


def _classes(text: str) -> tuple[str, ...]:
    from dashtraj.world.catalog import VEHICLE_CLASSES

    out = tuple(c.strip() for c in text.split(","))
    if "" in out:
        raise argparse.ArgumentTypeError(f"{text!r} has an empty class between commas")
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

    from dashtraj.cli._args import ArgumentError
    from dashtraj.outputs import atomic_output, check_output
    from dashtraj.world.recording import RunConfig, simulate
    from dashtraj.world.traffic import TrafficConfig

    out = check_output(args.output, overwrite=args.overwrite, kind="dir")
    if args.step > args.duration:
        raise ArgumentError(f"--step {args.step:g} s is longer than --duration "
                            f"{args.duration:g} s")
    config = RunConfig(map=args.town, seed=args.seed, duration_s=args.duration,
                       n_observers=args.observers, n_agents=args.agents,
                       n_twins=args.twins, until_target_arrives=args.until_target_arrives,
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
        # written into a temporary sibling and moved into place whole; Ctrl-C keeps the
        # readable partial recording (complete: false) as OUT.partial-N and says so
        with atomic_output(out, overwrite=args.overwrite, kind="dir", keep_partial=True) as tmp:
            summary = simulate(config, tmp, progress=progress)
    finally:
        if bar is not None:
            bar.close()
    info = {"recording": str(out), "vehicles": summary.vehicles,
            "frames": summary.frames, "truth_rows": summary.truth_rows,
            "simulated_s": summary.simulated_to_t,
            "target_arrived_t": summary.target_arrived_t, "complete": summary.complete}
    if args.json:
        print(json.dumps(info))
    else:
        arrived = (f"target arrived at t={summary.target_arrived_t:.1f} s"
                   if summary.target_arrived_t is not None else "target did not arrive")
        if summary.target_arrived_t is not None and not args.until_target_arrives:
            arrived += " (the others drove on; target_route.csv ends at its arrival)"
        print(f"{out}: {summary.vehicles} vehicles, {summary.frames} frames "
              f"({summary.simulated_to_t:.1f} s), {summary.truth_rows} truth rows; {arrived}")
    return 0


SIGHTINGS_DB_DEFAULTS = {"tracker": "ego", "localizer": "smoothed", "sample": 0.5}
"""`sightings` options of the camera pipeline and 'export', with their defaults."""


def run_sightings(args: argparse.Namespace) -> int:
    """Write oracle sightings of one vehicle to a CSV and print how many; returns 0."""
    from dashtraj.cli._args import ArgumentError
    from dashtraj.outputs import atomic_output, check_output
    from dashtraj.trajectory.io import write_sightings
    from dashtraj.world.oracle import OracleConfig, oracle_sightings
    from dashtraj.world.recording import Recording

    if args.recording == "export" or args.detector is not None:
        if args.oracle:
            raise ArgumentError("--oracle cannot be combined with --detector or 'export'")
        from dashtraj.cli.sightings_db import run_sightings_db

        for name, default in SIGHTINGS_DB_DEFAULTS.items():
            if getattr(args, name) is None:
                setattr(args, name, default)
        return run_sightings_db(args)
    for name in SIGHTINGS_DB_DEFAULTS:
        if getattr(args, name) is not None:
            raise ArgumentError(f"--{name} applies to the camera pipeline (--detector) and "
                                "'export' only, not to the oracle's sightings")
    check_output(args.output, overwrite=args.overwrite, kind="file")
    rec = Recording.open(args.recording)
    cfg = OracleConfig(vehicle=args.vehicle, max_distance_m=args.max_distance, noise=args.noise,
                       seed=args.seed)
    sightings = oracle_sightings(rec, cfg)
    with atomic_output(args.output, overwrite=args.overwrite, kind="file") as tmp:
        write_sightings(tmp, sightings)
    observers = len({s.observer_id for s in sightings})
    tracks = len({s.track_id for s in sightings})
    if not sightings:
        print(f"warning: no sightings of vehicle {args.vehicle} within "
              f"{args.max_distance:g} m of a camera; {args.output} has only its header",
              file=sys.stderr)
    print(f"{args.output}: {len(sightings)} sightings of vehicle {args.vehicle} by "
          f"{observers} observers in {tracks} tracks (noise {args.noise})")
    return 0
