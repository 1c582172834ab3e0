"""Re-identify and re-score finished from-pixels experiments with another ReID model.

`dashtraj experiments --sightings vision -o EXP` keeps every run's perception
(``EXP/<run>/recording/`` and ``sightings.db``). This script re-runs only what follows
perception: the appearance ReID with MODEL and its calibrated threshold, the gate, the
reconstruction and the scores, on the very same detections, tracks and positions; so two
ReID models are compared on identical perception. Each database is copied to a temporary
folder first (the embeddings of MODEL are added to the copy, never to EXP).

Usage:
    python scripts/reid_rescore.py EXP --reid-model M.onnx [--reid-threshold F.json]
        [--gate | --no-gate] [--same-camera-m M] [--slack-m M] [--radius-m M] [--max-speed-mps V]
        [--co-observed-m M] [--heading-min-m M] [--heading-window-s S]
        [--pin-anchor | --no-pin-anchor] [--watch | --no-watch] [--watch-range-m M] ...
        [--lookalike | --no-lookalike] [--lookalike-frac F] [--lookalike-gap S]
        [--split | --no-split] [--young-jump N] [--min-score S] [--no-pose-sigma]
        [--gallery-range M] [--route-range M] [--json]

Prints one row per run (ReID precision/recall, hmm and shortest-path SSPD over the whole
trip and the seen stretch) and the means, with the same aggregation as `experiments`.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from dataclasses import fields, replace
from pathlib import Path

GATE_NOTES = {
    "same_camera_m": "0: the rule before 2026-11-27, any two time-overlapping tracks of one "
                     "camera are two vehicles",
    "co_observed_m": "0: the rule before 2026-11-29, no cross-camera groups",
    "heading_min_m": "inf: no track shows its way",
}
"""What --help adds for some of the gate's settings (every `GateConfig` field is an option)."""


def main(argv: list[str] | None = None) -> int:
    from dashtraj.experiments import (
        SAMPLE_S,
        ExperimentConfig,
        aggregate,
        aggregate_reid,
        reconstruct_and_score,
    )
    from dashtraj.reid.embed import ReidEmbedder
    from dashtraj.reidentify.select import LookalikeRule
    from dashtraj.reidentify.vision import (
        LOOKALIKE,
        PIN_ANCHOR,
        SIGHTING_MIN_SCORE,
        SPLIT_TRACKS,
        VISION_GATE,
        WATCH,
        YOUNG_JUMP,
        load_threshold,
        target_from_db,
    )
    from dashtraj.roads import RoadMap
    from dashtraj.trajectory.gating import GateConfig
    from dashtraj.trajectory.watch import WatchConfig
    from dashtraj.world.recording import Recording

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("exp", type=Path, help="an experiments output folder (--sightings vision)")
    ap.add_argument("--reid-model", required=True, type=Path, help="ReID ONNX model")
    ap.add_argument("--reid-threshold", type=Path, default=None,
                    help="its threshold JSON (default: beside the model)")
    ap.add_argument("--gate", action=argparse.BooleanOptionalAction, default=None,
                    help="the road-network gate on or off (default: as each run was made)")
    gate_fields = [f.name for f in fields(GateConfig)]
    for field in gate_fields:  # --slack-m M etc.: VISION_GATE with that field replaced
        note = GATE_NOTES.get(field)
        ap.add_argument("--" + field.replace("_", "-"), type=float, default=None,
                        help=f"the gate's GateConfig.{field} (default: the library's "
                             f"VISION_GATE{'; ' + note if note else ''})")
    ap.add_argument("--pin-anchor", action=argparse.BooleanOptionalAction, default=PIN_ANCHOR,
                    help="the gate keeps the query's own track whatever the others say "
                         "(default: the library's, dashtraj.reidentify.vision.PIN_ANCHOR)")
    ap.add_argument("--watch", action=argparse.BooleanOptionalAction, default=None,
                    help="negative evidence in the gate: two tracks are two vehicles when every "
                         "way one car could have driven between them led through places the "
                         "cameras watched and saw empty (default: the library's, "
                         "dashtraj.reidentify.vision.WATCH, or on when a --watch-* setting "
                         "is given)")
    watch_fields = [f.name for f in fields(WatchConfig)]
    for field in watch_fields:  # --watch-range-m M etc.: WatchConfig with that field replaced
        ap.add_argument("--watch-" + field.replace("_", "-"),
                        type=int if field == "misses" else float, default=None,
                        help=f"the negative evidence's WatchConfig.{field} (default: the "
                             f"library's WatchConfig())")
    ap.add_argument("--lookalike", action=argparse.BooleanOptionalAction, default=None,
                    help="once a dropped candidate has shown a look-alike, keep only the tracks "
                         "linked to the query's by short unseen stretches (default: the "
                         "library's, dashtraj.reidentify.vision.LOOKALIKE, or on when a "
                         "--lookalike-* setting is given)")
    ap.add_argument("--lookalike-frac", type=float, default=None, metavar="F",
                    help="LookalikeRule.distance_frac (default: LookalikeRule()'s)")
    ap.add_argument("--lookalike-gap", type=float, default=None, metavar="S",
                    help="LookalikeRule.max_gap_s, seconds (default: LookalikeRule()'s)")
    ap.add_argument("--split", action=argparse.BooleanOptionalAction, default=SPLIT_TRACKS,
                    help="cut tracks where their crops' look changes (default: the library's, "
                         "dashtraj.reidentify.vision.SPLIT_TRACKS)")
    ap.add_argument("--young-jump", type=int, default=YOUNG_JUMP, metavar="N",
                    help="cut a track where its box jumps (no overlap with the one before) "
                         "before its N-th detection (default: the library's, "
                         "dashtraj.reidentify.vision.YOUNG_JUMP; 0: never)")
    ap.add_argument("--min-score", type=float, default=SIGHTING_MIN_SCORE,
                    help="use only detections scored at least this (default: the library's, "
                         "dashtraj.reidentify.vision.SIGHTING_MIN_SCORE; 0: all)")
    ap.add_argument("--no-pose-sigma", action="store_true",
                    help="runs made with --pose-noise: the HMM without the pose errors in its "
                         "emission σ (as before 2026-11-29)")
    ap.add_argument("--gallery-range", type=float, default=None, metavar="M",
                    help="the gallery and the sightings within M metres (default: the run's "
                         "own; crops beyond the run's perception range were never stored)")
    ap.add_argument("--route-range", type=float, default=None, metavar="M",
                    help="the accepted tracks' detections within M metres join the route's "
                         "sightings (default: the run's own setting)")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = ap.parse_args(argv)

    runs = sorted(p.parent for p in args.exp.glob("*/summary.json")
                  if (p.parent / "sightings.db").is_file())
    if not runs:
        print(f"{args.exp}: no runs with summary.json and sightings.db", file=sys.stderr)
        return 2
    th = load_threshold(args.reid_model, args.reid_threshold)
    changes = {k: getattr(args, k) for k in gate_fields if getattr(args, k) is not None}
    gate_cfg = replace(VISION_GATE, **changes) if changes else None
    wchanges = {k: getattr(args, "watch_" + k) for k in watch_fields
                if getattr(args, "watch_" + k) is not None}
    watch = (WatchConfig(**wchanges) if wchanges and args.watch is not False
             else WATCH if args.watch is None else args.watch)
    lchanges = {k: v for k, v in (("distance_frac", args.lookalike_frac),
                                   ("max_gap_s", args.lookalike_gap)) if v is not None}
    lookalike = (LookalikeRule(**lchanges) if lchanges and args.lookalike is not False
                 else LOOKALIKE if args.lookalike is None else args.lookalike)
    embedder = ReidEmbedder(args.reid_model, threads=1)
    summaries, rows = [], []
    with tempfile.TemporaryDirectory(prefix="reid_rescore_") as tmp:
        for run in runs:
            old = json.loads((run / "summary.json").read_text())
            config = ExperimentConfig.from_dict(old["config"])
            rec = Recording.open(run / "recording")
            road_map = RoadMap.from_file(rec.map_path)
            db = Path(tmp) / f"{run.name}.db"
            gate_on = config.gate if args.gate is None else args.gate
            shutil.copyfile(run / "sightings.db", db)
            tt = target_from_db(db, road_map, int(rec.meta.get("target_vehicle_id", 0)),
                                embedder=embedder, threshold=th.calibration.threshold,
                                recipe=th.calibration.recipe,
                                gate=(gate_cfg or True) if gate_on else False,
                                max_distance_m=config.max_distance_m, sample_s=SAMPLE_S,
                                pin_anchor=args.pin_anchor, split=args.split,
                                young_jump=args.young_jump,
                                min_score=args.min_score,
                                gallery_m=(config.gallery_m if args.gallery_range is None
                                           else args.gallery_range),
                                route_m=(config.route_m if args.route_range is None
                                         else args.route_range), watch=watch,
                                lookalike=lookalike)
            results, _, _ = reconstruct_and_score(road_map, rec.target_route, tt.sightings,
                                                  config.methods,
                                                  pose_noise=None if args.no_pose_sigma
                                                  else config.pose_noise)
            summary = {**tt.summary, "methods": results}
            summaries.append(summary)
            row = {"run": run.name, "reid_precision": summary.get("reid_precision"),
                   "reid_recall": summary.get("reid_recall"),
                   **{f"{m}_{k}": r[k] for m, r in results.items()
                      for k in ("sspd_m", "seen_sspd_m")}}
            rows.append(row)
            if not args.json:
                print(" ".join(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}"
                               for k, v in row.items()), flush=True)
    out = {"model": str(args.reid_model), "threshold": th.calibration.threshold,
           "runs": rows, "methods": aggregate(summaries), "reid": aggregate_reid(summaries)}
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        for m, a in out["methods"].items():
            print(f"{m}: SSPD whole {a['sspd_whole_m']:.2f} m, seen {a['sspd_seen_m']:.2f} m, "
                  f"Hausdorff seen {a['hausdorff_seen_m']:.1f} m")
        print(f"ReID over all tracks: {out['reid']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
