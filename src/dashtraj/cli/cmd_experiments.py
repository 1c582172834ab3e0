"""`dashtraj experiments`: the paper's ten driving experiments, scored."""

from __future__ import annotations

import json
from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("experiments",
                       help="run the paper's ten driving experiments (5 × town01, 5 × town10)")
    p.add_argument("--towns", nargs="+", default=["town01", "town10"],
                   help="towns (names or .xodr paths)")
    p.add_argument("--seeds", type=int, default=5, help="experiments per town (seeds 0..N-1)")
    p.add_argument("--noise", choices=("paper", "none"), default="paper")
    p.add_argument("-o", "--output", default="runs/experiments", help="output folder")
    p.add_argument("--plots", action="store_true", help="also save a picture per experiment")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    from dashtraj.experiments import (
        PAPER_SSPD_M,
        ExperimentConfig,
        aggregate,
        plot_experiment,
        run_experiment,
    )

    out = Path(args.output)
    summaries = []
    for town in args.towns:
        for seed in range(args.seeds):
            cfg = ExperimentConfig(town=town, seed=seed, noise=args.noise)
            name = f"{Path(town).stem}_seed{seed}"
            res = run_experiment(cfg, out / name)
            if args.plots:
                plot_experiment(res, out / name / "trajectory.png")
            summaries.append(res.summary)
            if not args.json:
                m = res.summary["methods"]
                row = "  ".join(f"{k} {v['sspd_m']:6.2f} / {v['seen_sspd_m']:5.2f} m"
                                for k, v in m.items())
                print(f"{name:16s} {res.summary['sightings']:4d} sightings, "
                      f"{res.summary['observers_that_saw_target']} observers   {row}")
    agg = aggregate(summaries)
    (out / "summary.json").write_text(json.dumps({"experiments": summaries, "aggregate": agg},
                                                 indent=2) + "\n")
    if args.json:
        print(json.dumps(agg, indent=2))
        return 0
    print(f"\nmean over {len(summaries)} experiments (SSPD whole trip / seen stretch; "
          f"the paper: {PAPER_SSPD_M} m whole trip):")
    for method, a in agg.items():
        print(f"  {method:14s} SSPD {a['mean_sspd_m']:6.2f} m / {a['mean_seen_sspd_m']:5.2f} m"
              f"   Hausdorff {a['mean_hausdorff_m']:6.2f} m / {a['mean_seen_hausdorff_m']:6.2f} m")
    return 0
