"""`dashtraj experiments`: the paper's ten driving experiments, scored."""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

from dashtraj.cli._args import HelpFormatter, count, seed_list
from dashtraj.cli._vision_args import add_vision_args
from dashtraj.outputs import add_output_args

DESCRIPTION = """\
Run the paper's driving experiments (§II.G) end to end and score them: for every town and
seed, simulate the town with 4 observers, one target and 20 agents until the target arrives,
take the target's sightings within 15 m of a dashcam from pixels (--sightings vision, the
default; see below) or from the oracle (--sightings oracle: the truth with the paper's
localization noise), reconstruct its route with the paper's method (shortest-path) and with
dashtraj's HMM, and score both against the true route with SSPD and Hausdorff distance
(metres), over the whole trip and over the stretch between the first and last sighting.
The default is the paper's set: five seeds in town01 and five in town10. Progress lines go
to stderr (-q: none); each row ends with the run's wall and CPU seconds.

--sightings detections runs the camera pipeline instead of the oracle (perceive with the
oracle detector: render, track, localize, map-match into OUT/<run>/sightings.db) and picks
the target's tracks by their true identity: the error of tracking and localization alone
(no appearance ReID yet). ReID precision/recall are reported per experiment and over all
tracks; with both sources the target's tracks are picked by identity, so they are 1.0 by
construction. --twins N adds N agents of the target's exact model and colour; with
--reid look-alike every track of the target and its twins is a candidate (appearance that
cannot tell exact look-alikes apart) and the spatio-temporal gate on the lane graph keeps
the chain the target could have driven (--no-gate: keep all, the paper's way).

--sightings vision (the default; --reid look-alike defaults to the oracle) runs the paper's
whole pipeline from pixels: perceive every observer
(--detector: the shipped ONNX model, or oracle) into OUT/<run>/sightings.db, embed every
crop with the ReID model, take the target's first crop within 15 m as the query, decide
per observer track with the threshold calibrated on TRAINING recordings (beside the model;
`dashtraj reid-threshold`), gate on the lane graph, then reconstruct and score as above,
with the accepted tracks' detections out to 20 m in the route (--route-range; 15 m: none).
ReID precision/recall are then measured against each track's true identity.

--ablation runs the error budget instead (the paper's Table IV with numbers): each
experiment is perceived with exact boxes and with the detector model, and the target's
sightings are taken with stages turned real one at a time (detection, tracking,
localization, ReID); it prints the mean SSPD each real stage adds and writes
OUT/ablation.json.

--drives DRIVE... runs each recorded drive as an experiment instead of simulating (what
dashtraj carla-record writes from a CARLA server, or dashtraj render --png --depth from a
recording): its images are perceived as they are, its truth.csv names the target (role
'target') and scores the re-identification, its target_route.csv scores the route.

Writes OUT/<town>_seed<N>/ (recording/, sightings.csv, truth.csv, estimate_<method>.csv,
summary.json; OUT/<drive folder name>/ with --drives, no recording/) and OUT/summary.json
(every experiment and the means)."""


def register(sub) -> None:
    p = sub.add_parser("experiments",
                       help="run the paper's ten driving experiments (5 × town01, 5 × town10)",
                       description=DESCRIPTION,
                       formatter_class=HelpFormatter)
    p.add_argument("--towns", nargs="+", default=None,
                   help="towns (built-in names or .xodr paths; default town01 town10)")
    p.add_argument("--seeds", type=seed_list, default=None,
                   help="seeds per town: a range A-B, a list a,b,c, or a count N (0..N-1; "
                        "default 0-4)")
    p.add_argument("--noise", choices=("paper", "none"), default="paper",
                   help="localization noise of the oracle sightings")
    add_vision_args(p, default_sightings=None)
    p.add_argument("--twins", type=count, default=0, metavar="N",
                   help="agents of the target's exact model and colour (default 0)")
    p.add_argument("--reid", choices=("identity", "look-alike", "appearance"), default=None,
                   help="pick the target's tracks by identity (reference), among every "
                        "look-alike's (target and twins) with the gate, or by appearance "
                        "(vision's default)")
    p.add_argument("--gate", action=argparse.BooleanOptionalAction, default=True,
                   help="with --reid look-alike or appearance: the spatio-temporal gate "
                        "(default on)")
    p.add_argument("--drives", nargs="+", default=None, metavar="DRIVE",
                   help="run each drive (images, camera poses, truth.csv with one role "
                        "'target', target_route.csv: what carla-record writes, or render) "
                        "as an experiment instead of simulating: from pixels, its images "
                        "as they are (no --towns/--seeds/--twins/--size/--look)")
    p.add_argument("--ablation", action="store_true",
                   help="the error budget: each stage oracle vs real, the SSPD each adds")
    p.add_argument("-o", "--output", default="runs/experiments", help="output folder")
    add_output_args(p)
    p.add_argument("--plots", action="store_true", help="also save a picture per experiment")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("-q", "--quiet", action="store_true",
                   help="no progress lines on stderr")
    p.set_defaults(func=run)


def drive_runs(args, base) -> list:
    """(config, name) of each ``--drives`` folder, checked before any work: a drive
    (`Drive.open`), with truth and a target route; options that need a simulation are
    refused."""
    from dashtraj.cli._args import ArgumentError
    from dashtraj.datasets.drive import Drive

    if base.sightings != "vision":
        raise ArgumentError("--drives runs from pixels: leave --sightings out")
    if base.reid == "look-alike":
        raise ArgumentError("--drives with --reid look-alike: a drive has no twins to tell")
    for flag, given in (("--towns", args.towns is not None),
                        ("--seeds", args.seeds is not None), ("--twins", args.twins),
                        ("--size", args.size is not None), ("--look", args.look is not None)):
        if given:
            raise ArgumentError(f"{flag} does not apply to --drives (their images are what "
                                "they are)")
    runs, seen = [], set()
    for d in args.drives:
        drive = Drive.open(d)
        if drive.truth is None:
            raise ArgumentError(f"--drives {d}: no truth.csv (the experiment scores the "
                                "re-identification against it)")
        if not (drive.path / "target_route.csv").is_file():
            raise ArgumentError(f"--drives {d}: no target_route.csv (the true route)")
        name = Path(d).resolve().name
        if name in seen:
            raise ArgumentError(f"--drives {d}: two drives named {name!r}")
        seen.add(name)
        runs.append((replace(base, drive=str(drive.path), town=str(drive.map_path), seed=0,
                             image_size=None, look=None), name))
    return runs


def town_label(town: str) -> str:
    """How a town is named in folders and lines: ``town01`` for a built-in, a file's stem."""
    return Path(town).stem if town.lower().endswith(".xodr") else town.lower()


def run(args) -> int:
    from dashtraj.cli._args import ArgumentError
    from dashtraj.cli._vision_args import (
        VISION_EVERY_S,
        VISION_SIZE,
        check_reid_model,
        vision_settings,
    )
    from dashtraj.experiments import (
        PAPER_SSPD_M,
        ExperimentConfig,
        aggregate,
        aggregate_reid,
        figures,
        plot_experiment,
        run_experiment,
    )
    from dashtraj.outputs import atomic_output, check_output
    from dashtraj.world.towns import UnknownTownError, resolve_map

    out = check_output(args.output, overwrite=args.overwrite, kind="dir")
    if args.drives is None:  # the paper's ten
        args.towns = args.towns or ["town01", "town10"]
        args.seeds = args.seeds or seed_list("0-4")
    elif args.ablation:
        raise ArgumentError("--drives with --ablation: the error budget needs the "
                            "renderer's exact boxes (a simulated recording)")
    if args.sightings is None:  # from pixels, except the look-alike test (oracle tracks)
        args.sightings = "oracle" if args.reid == "look-alike" else "vision"
    vision = vision_settings(args)
    if args.ablation:
        vision["sightings"] = "vision"
        vision["route_m"] = None  # the error budget's stages: the paper's 15 m
        if args.every is None:
            vision["every_s"] = VISION_EVERY_S
    reid = args.reid or ("appearance" if vision["sightings"] == "vision" else "identity")
    if args.ablation and args.pose_noise is not None:
        raise ArgumentError("--ablation with --pose-noise: the error budget's stages are "
                            "measured from the exact poses (give --pose-noise without it)")
    if args.ablation and args.calibrate_pitch:
        raise ArgumentError("--ablation with --calibrate-pitch: the error budget's stages are "
                            "measured from the exact poses (give --calibrate-pitch without "
                            "it)")
    if args.ablation and args.live_relink:
        raise ArgumentError("--ablation with --live-relink: the error budget's tracking stage "
                            "is the tracker's own ids (give --live-relink without it)")
    for flag, value in (("--gallery-range", args.gallery_range),
                        ("--route-range", args.route_range)):
        if args.ablation and value is not None:
            raise ArgumentError(f"--ablation with {flag}: the error budget's stages are "
                                f"measured with the paper's 15 m (give {flag} without it)")
    if args.ablation and reid != "appearance":
        raise ArgumentError(f"--ablation with --reid {reid}: the ablation's last stage is "
                            "appearance ReID (leave --reid out)")
    base = ExperimentConfig(noise=args.noise, twins=args.twins, reid=reid, gate=args.gate,
                            **{**vision, "image_size": vision["image_size"]
                               or (VISION_SIZE if args.ablation else None)})
    check_reid_model(base)
    for town in args.towns or ():  # every town named must exist before hours of work start
        try:
            resolve_map(town)
        except UnknownTownError as exc:
            raise ArgumentError(f"--towns {town!r} is neither a file nor a built-in town "
                                f"({exc})") from None
    if args.ablation:
        return run_ablation_suite(args, base, out)
    from dashtraj.cli.cmd_demo import stage_printer

    if args.drives is not None:
        runs = drive_runs(args, base)
    else:
        runs = [(replace(base, town=town, seed=seed), f"{town_label(town)}_seed{seed}")
                for town in args.towns for seed in args.seeds]
    summaries = []
    names = []
    header = False
    total = {"wall_s": 0.0, "cpu_s": 0.0}
    n_runs = len(runs)
    with atomic_output(out, overwrite=args.overwrite, kind="dir") as tmp:
        for cfg, name in runs:
            say = None if args.quiet else stage_printer(
                f"{name} {len(names) + 1}/{n_runs}")
            res = run_experiment(cfg, tmp / name, say=say)
            if args.plots:
                plot_experiment(res, tmp / name / "trajectory.png")
            for k in total:
                total[k] += sum(v[k] for v in res.timing.values())
            summaries.append(res.summary)
            names.append(name)
            if args.json:
                continue
            m = res.summary["methods"]
            if not header:
                print(f"{'experiment':16s} {'sightings':>9s} {'observers':>9s}   "
                      + "  ".join(f"{k + ' SSPD whole / seen':>34s}" for k in cfg.methods))
                header = True
            row = "  ".join(f"{m[k]['sspd_m']:24.2f} / {m[k]['seen_sspd_m']:5.2f} m"
                            if k in m else f"{'(no sightings)':>34s}" for k in cfg.methods)
            wall = sum(v["wall_s"] for v in res.timing.values())
            cpu = sum(v["cpu_s"] for v in res.timing.values())
            print(f"{name:16s} {res.summary['sightings']:9d} "
                  f"{res.summary['observers_that_saw_target']:9d}   {row}   "
                  f"({wall:.0f} s, CPU {cpu:.0f} s)", flush=True)
        agg = aggregate(summaries)
        reid = aggregate_reid(summaries)
        (tmp / "summary.json").write_text(
            json.dumps({"experiments": summaries, "aggregate": agg, "reid": reid}, indent=2)
            + "\n")
    if args.json:
        mean = {"methods": {m: {k: a[k] for k in ("sspd_whole_m", "sspd_seen_m",
                                                  "hausdorff_whole_m", "hausdorff_seen_m")}
                            for m, a in agg.items()},
                "experiments": len(summaries), **reid}
        print(json.dumps({"experiments": [figures(n, s) for n, s in zip(names, summaries,
                                                                          strict=True)],
                          "mean": mean, "aggregate": agg, "timing": total}, indent=2))
        return 0
    print(f"\nmean over {len(summaries)} experiments (SSPD whole trip / seen stretch; "
          f"the paper: {PAPER_SSPD_M} m whole trip):")
    for method, a in agg.items():
        print(f"  {method:14s} SSPD {a['mean_sspd_m']:6.2f} m / {a['mean_seen_sspd_m']:5.2f} m"
              f"   Hausdorff {a['mean_hausdorff_m']:6.2f} m / {a['mean_seen_hausdorff_m']:6.2f} m")
    how = ("by construction: tracks picked by their true identity" if reid == "identity"
           else f"look-alikes of the target, gate {'on' if args.gate else 'off'}"
           if reid == "look-alike"
           else f"appearance, threshold calibrated on training recordings, gate "
                f"{'on' if args.gate else 'off'}")
    p_, r_ = reid["reid_precision"], reid["reid_recall"]
    print(f"  ReID over {reid['reid_true_matches'] + reid['reid_false_matches']} accepted "
          f"tracks: precision {'-' if p_ is None else f'{p_:.3f}'}, recall "
          f"{'-' if r_ is None else f'{r_:.3f}'} ({how})")
    if reid.get("reid_sighting_precision") is not None:
        tp = reid["reid_sightings_true"]
        print(f"  per sighting: precision {reid['reid_sighting_precision']:.3f} ({tp} of the "
              f"{tp + reid['reid_sightings_false']} accepted show the target), recall "
              f"{reid['reid_sighting_recall']:.3f} ({tp} of the "
              f"{tp + reid['reid_sightings_missed']} that show it)")
    if "reid_misses_by_cause" in reid:
        c = reid["reid_misses_by_cause"]
        print(f"  the target's {reid['reid_misses']} missed tracks: {c['threshold']} above the "
              f"threshold, {c['gate']} dropped by the gate, {c['no_usable_crop']} without a "
              "usable crop")
    print(f"time: {total['wall_s']:.0f} s wall, {total['cpu_s']:.0f} CPU-s for "
          f"{len(summaries)} experiments")
    print(f"files: {out}/")
    return 0


def run_ablation_suite(args, base, out: Path) -> int:
    """``--ablation``: every experiment's error budget, the mean SSPD each real stage adds."""
    from dashtraj.ablation import ROWS, SOURCES, budget, run_ablation
    from dashtraj.outputs import atomic_output

    results, names = [], []
    with atomic_output(out, overwrite=args.overwrite, kind="dir") as tmp:
        for town in args.towns:
            for seed in args.seeds:
                cfg = replace(base, town=town, seed=seed)
                name = f"{town_label(town)}_seed{seed}"
                res = run_ablation(cfg, tmp / name)
                results.append(res)
                names.append(name)
                if not args.json:
                    cells = "  ".join(
                        f"{r[0]}: " + (f"{res['rows'][r[0]]['methods']['hmm']['sspd_whole_m']:.2f}"
                                       if "hmm" in res["rows"][r[0]]["methods"] else "-")
                        for r in ROWS)
                    print(f"{name:16s} hmm SSPD whole  {cells}", flush=True)
        b = budget(results)
        summary = {"experiments": names, "rows": [r[0] for r in ROWS], "sources": SOURCES,
                   "detector": base.detector, "reid_model": results[0]["reid_model"]
                   if results else None, "look": results[0]["look"] if results else None,
                   "budget": b, "per_experiment": dict(zip(names, results, strict=True))}
        (tmp / "ablation.json").write_text(json.dumps(summary, indent=2) + "\n")
    if args.json:
        print(json.dumps({k: summary[k] for k in ("experiments", "rows", "sources", "detector",
                                                  "reid_model", "look", "budget")}, indent=2))
        return 0
    if not b:
        print("\nno experiment had sightings in any row: nothing to compare")
    for method, m in b.items():
        print(f"\n{method}: mean SSPD whole / seen (m) over the experiments with sightings in "
              f"the row; a stage adds the mean difference to the row before")
        for r in ROWS:
            row = m["rows"].get(r[0])
            cell = ("no sightings" if row is None else
                    f"{row['sspd_whole_m']:6.2f} / {row['sspd_seen_m']:6.2f}  "
                    f"({row['experiments']} exp.)")
            imp = m["impact"].get(r[0])
            add = ("" if imp is None else
                   f"   adds {imp['sspd_whole_m']:+6.2f} / {imp['sspd_seen_m']:+6.2f}  "
                   f"({SOURCES[r[0]]}; {imp['experiments']} exp.)")
            print(f"  {r[0]:14s} {cell}{add}")
    print(f"files: {out}/")
    return 0
