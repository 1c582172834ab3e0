"""`dashtraj experiments`: the paper's ten driving experiments, scored."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from dashtraj.cli._args import positive_int
from dashtraj.outputs import add_output_args

DESCRIPTION = """\
Run the paper's driving experiments (§II.G) end to end and score them: for every town and
seed, simulate the town with 4 observers, one target and 20 agents until the target arrives,
take oracle sightings of the target within 15 m of a dashcam (with the paper's localization
noise by default), reconstruct its route with the paper's method (shortest-path) and with
dashtraj's HMM, and score both against the true route with SSPD and Hausdorff distance
(metres), over the whole trip and over the stretch between the first and last sighting.
The default is the paper's set: five seeds in town01 and five in town10.

Writes OUT/<town>_seed<N>/ (recording/, sightings.csv, truth.csv, estimate_<method>.csv,
summary.json) and OUT/summary.json (every experiment and the means)."""


def register(sub) -> None:
    p = sub.add_parser("experiments",
                       help="run the paper's ten driving experiments (5 × town01, 5 × town10)",
                       description=DESCRIPTION,
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--towns", nargs="+", default=["town01", "town10"],
                   help="towns (built-in names or .xodr paths)")
    p.add_argument("--seeds", type=positive_int, default=5,
                   help="experiments per town (seeds 0..N-1)")
    p.add_argument("--noise", choices=("paper", "none"), default="paper",
                   help="localization noise of the oracle sightings")
    p.add_argument("-o", "--output", default="runs/experiments", help="output folder")
    add_output_args(p)
    p.add_argument("--plots", action="store_true", help="also save a picture per experiment")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=run)


def town_label(town: str) -> str:
    """How a town is named in folders and lines: ``town01`` for a built-in, a file's stem."""
    return Path(town).stem if town.lower().endswith(".xodr") else town.lower()


def run(args) -> int:
    from dashtraj.cli._args import ArgumentError
    from dashtraj.experiments import (
        PAPER_SSPD_M,
        ExperimentConfig,
        aggregate,
        plot_experiment,
        run_experiment,
    )
    from dashtraj.outputs import atomic_output, check_output
    from dashtraj.world.towns import UnknownTownError, resolve_map

    out = check_output(args.output, overwrite=args.overwrite, kind="dir")
    for town in args.towns:  # every town named must exist before hours of work start
        try:
            resolve_map(town)
        except UnknownTownError as exc:
            raise ArgumentError(f"--towns {town!r} is neither a file nor a built-in town "
                                f"({exc})") from None
    summaries = []
    header = False
    with atomic_output(out, overwrite=args.overwrite, kind="dir") as tmp:
        for town in args.towns:
            for seed in range(args.seeds):
                cfg = ExperimentConfig(town=town, seed=seed, noise=args.noise)
                name = f"{town_label(town)}_seed{seed}"
                res = run_experiment(cfg, tmp / name)
                if args.plots:
                    plot_experiment(res, tmp / name / "trajectory.png")
                summaries.append(res.summary)
                if args.json:
                    continue
                m = res.summary["methods"]
                if not header:
                    print(f"{'experiment':16s} {'sightings':>9s} {'observers':>9s}   "
                          + "  ".join(f"{k + ' SSPD whole / seen':>34s}" for k in cfg.methods))
                    header = True
                row = "  ".join(f"{m[k]['sspd_m']:23.2f} / {m[k]['seen_sspd_m']:5.2f} m"
                                if k in m else f"{'(no sightings)':>34s}" for k in cfg.methods)
                print(f"{name:16s} {res.summary['sightings']:9d} "
                      f"{res.summary['observers_that_saw_target']:9d}   {row}", flush=True)
        agg = aggregate(summaries)
        (tmp / "summary.json").write_text(
            json.dumps({"experiments": summaries, "aggregate": agg}, indent=2) + "\n")
    if args.json:
        print(json.dumps(agg, indent=2))
        return 0
    print(f"\nmean over {len(summaries)} experiments (SSPD whole trip / seen stretch; "
          f"the paper: {PAPER_SSPD_M} m whole trip):")
    for method, a in agg.items():
        print(f"  {method:14s} SSPD {a['mean_sspd_m']:6.2f} m / {a['mean_seen_sspd_m']:5.2f} m"
              f"   Hausdorff {a['mean_hausdorff_m']:6.2f} m / {a['mean_seen_hausdorff_m']:6.2f} m")
    print(f"files: {out}/")
    return 0
