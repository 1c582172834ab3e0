"""`dashtraj demo`: the main job on the built-in world, end to end, from pixels.

simulate (observers, one target, agents) → perceive every observer's dashcam frames
(shipped detector, tracker, localizer) → embed the crops (shipped ReID model) →
re-identify the target (calibrated threshold, road-network gate) → reconstruct its
route (the paper's shortest-path method and dashtraj's HMM) → score against the true
route (SSPD, Hausdorff) → a top view like the paper's Fig. 6. ``--sightings oracle``:
the recording's truth with the paper's localization noise instead of pixels.
"""

from __future__ import annotations

import argparse
import json
import sys

from dashtraj.cli._args import HelpFormatter, count, duration, seed
from dashtraj.cli._vision_args import add_vision_args
from dashtraj.outputs import add_output_args

DESCRIPTION = """\
The main job on a built-in town, end to end from pixels: simulate one target car driving
to a destination with observer cars (dashcams) and agents around it, until it arrives;
perceive every observer's frames (the shipped detector, or --detector oracle; 640x360, 5
frames/s, observers in --workers processes) into OUT/sightings.db; embed the crops with the
shipped ReID model; take the target's first crop within 15 m as the query and pick its
tracks with the threshold calibrated on training recordings and the road-network gate;
reconstruct its route with the paper's method (shortest-path) and dashtraj's HMM; score
both against the true route (SSPD, Hausdorff, metres) and draw a top view like the paper's
Fig. 6, each used sighting marked as a true or false match. Every stage prints a progress
line (stderr) and the summary ends with the wall and CPU seconds of each.

--sightings oracle takes the recording's truth within 15 m of a dashcam with the paper's
localization noise instead of pixels (the reference; seconds).

Writes OUT/recording/, sightings.csv, truth.csv, estimate_<method>.csv, summary.json and
trajectory.png. The built-in towns town01 and town10 are generated after CARLA's (not
CARLA's assets); a CARLA .xodr file works too."""


def register(sub) -> None:
    p = sub.add_parser("demo", help="simulate, sight, reconstruct and score on a built-in town",
                       description=DESCRIPTION,
                       formatter_class=HelpFormatter)
    p.add_argument("--town", default="town10", help="built-in town name or .xodr path")
    p.add_argument("--observers", type=count, default=4, help="observer cars with dashcams")
    p.add_argument("--agents", type=count, default=20, help="other cars")
    p.add_argument("--seed", type=seed, default=7, help="seed of the run and of the noise")
    p.add_argument("--duration", type=duration, default=180.0,
                   help="longest drive, seconds (the run ends when the target arrives)")
    p.add_argument("--noise", choices=("paper", "none"), default="paper",
                   help="localization noise of the oracle sightings")
    add_vision_args(p, default_sightings="vision")
    p.add_argument("--gate", action=argparse.BooleanOptionalAction, default=True,
                   help="vision: the spatio-temporal gate after the appearance decision")
    p.add_argument("-o", "--output", default="runs/demo", help="output folder")
    add_output_args(p)
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def progress_bar(total_s: float, quiet: bool, desc: str = "simulate"):
    """(callback, bar) for `simulate`'s progress, or (None, None) when quiet / not a TTY."""
    if quiet or not sys.stderr.isatty():
        return None, None
    from tqdm import tqdm

    bar = tqdm(total=total_s, unit="sim s", desc=desc, file=sys.stderr,
               bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} s [{elapsed}<{remaining}]")
    done = [0.0]

    def update(t: float) -> None:
        if t - done[0] >= 1.0:
            bar.update(t - done[0])
            done[0] = t

    return update, bar


def print_scores(summary: dict) -> None:
    results = summary["methods"]
    if not results:
        print("no observer came within 15 m of the target: nothing to reconstruct")
        return
    print(f"{'':16s}{'whole trip':^28s}{'seen stretch (first→last sighting)':^40s}")
    print(f"{'method':16s}{'SSPD':>10s}{'Hausdorff':>14s}{'SSPD':>18s}{'Hausdorff':>14s}")
    for method, r in results.items():
        print(f"{method:16s}{r['sspd_m']:8.2f} m{r['hausdorff_m']:12.2f} m"
              f"{r['seen_sspd_m']:16.2f} m{r['seen_hausdorff_m']:12.2f} m")


def stage_printer(name: str):
    """A ``say`` callback: ``[name   12.3 s] line`` on stderr (seconds since created)."""
    import time

    t0 = time.perf_counter()

    def say(line: str) -> None:
        print(f"[{name} {time.perf_counter() - t0:6.1f} s] {line}", file=sys.stderr, flush=True)

    return say


def timing_line(timing: dict) -> str:
    """``time: simulate 2.1 s (CPU 2.0 s), ...; total 80.3 s (CPU 150.2 s)``."""
    parts = [f"{k} {v['wall_s']:.1f} s (CPU {v['cpu_s']:.1f} s)" for k, v in timing.items()]
    wall = sum(v["wall_s"] for v in timing.values())
    cpu = sum(v["cpu_s"] for v in timing.values())
    return f"time: {', '.join(parts)}; total {wall:.1f} s (CPU {cpu:.1f} s)"


def run(args) -> int:
    from dashtraj.cli._vision_args import check_reid_model, vision_settings
    from dashtraj.experiments import (
        ExperimentConfig,
        plot_experiment,
        reid_range_of,
        run_experiment,
    )
    from dashtraj.outputs import atomic_output, check_output

    out = check_output(args.output, overwrite=args.overwrite, kind="dir")
    vision = vision_settings(args)
    config = ExperimentConfig(town=args.town, seed=args.seed, observers=args.observers,
                              agents=args.agents, duration_s=args.duration, noise=args.noise,
                              reid="appearance" if vision["sightings"] == "vision" else "identity",
                              gate=args.gate, **vision)
    check_reid_model(config)
    from dashtraj.cli._args import ArgumentError
    from dashtraj.world.towns import UnknownTownError, resolve_map

    try:  # before any work starts
        resolve_map(args.town)
    except UnknownTownError as exc:
        raise ArgumentError(f"--town {args.town!r} is neither an .xodr file nor a built-in "
                            f"town ({exc})") from None
    update, bar = progress_bar(args.duration, args.quiet)
    say = None if args.quiet else stage_printer("demo")
    with atomic_output(out, overwrite=args.overwrite, kind="dir") as tmp:
        try:
            result = run_experiment(config, tmp, progress=update, say=say)
        finally:
            if bar is not None:
                bar.close()
        from dashtraj.experiments import Stages

        st = Stages(say)
        st.start("picture", "picture: trajectory.png")
        plot_experiment(result, tmp / "trajectory.png")
        timing = {**result.timing, **st.stop()}
        png = out / "trajectory.png"
        summary = {**result.summary, "picture": str(png)}
        (tmp / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    if args.json:
        print(json.dumps({**summary, "timing": timing}, indent=2))
        return 0
    arrived = (f"target arrived at {summary['target_arrived_t']:.1f} s"
               if summary["target_arrived_t"] is not None else "target did not arrive")
    print(f"{config.town}: {summary['vehicles']} vehicles, {summary['simulated_s']:.1f} s "
          f"simulated, {arrived}, true route {summary['true_route_m']:.0f} m")
    src = (f"noise: {config.noise}" if config.sightings == "oracle" else
           f"from pixels, detector {config.detector if config.sightings == 'vision' else 'oracle'}")
    if summary.get("route_sightings_beyond"):
        src += (f"; {summary['route_sightings_beyond']} of them beyond "
                f"{reid_range_of(config):g} m, within the route range "
                f"{config.route_m:g} m")
    print(f"{summary['sightings']} sightings of the target by "
          f"{summary['observers_that_saw_target']} observers ({src})")
    if config.sightings == "vision" and config.reid == "appearance":
        p_, r_ = summary.get("reid_precision"), summary.get("reid_recall")
        print(f"ReID: {summary['reid_true_matches']} true and {summary['reid_false_matches']} "
              f"false matches accepted, {summary['reid_misses']} of the target's tracks missed "
              f"(precision {'-' if p_ is None else f'{p_:.2f}'}, recall "
              f"{'-' if r_ is None else f'{r_:.2f}'}; gate {'on' if config.gate else 'off'})")
    print_scores(summary)
    if summary["methods"]:
        print(f"(the paper: mean SSPD 5.13 m over ten experiments; the seen stretch is "
              f"{summary['seen_route_m']:.0f} of {summary['true_route_m']:.0f} m)")
    print(timing_line(timing))
    print(f"files: {out}/  picture: {png}")
    return 0
