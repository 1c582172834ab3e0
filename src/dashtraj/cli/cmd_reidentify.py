"""`dashtraj reidentify DB --track OBS:TRACK --map MAP -o S.csv`: the paper's ``calc_traj``
on any sightings database, with the query a track the user points at."""

from __future__ import annotations

import argparse
import json


def _track(text: str) -> tuple[int, int]:
    try:
        o, t = (int(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected OBSERVER:TRACK (two integers), got "
                                         f"{text!r}") from None
    if o < 0 or t < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: the observer id is >= 0 and the track id "
                                         ">= 1")
    return o, t


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `reidentify` command."""
    from dashtraj.cli._args import positive_float
    from dashtraj.cli._vision_args import add_lookalike_arg, add_range_args, add_watch_arg
    from dashtraj.outputs import add_output_args

    p = subparsers.add_parser(
        "reidentify",
        help="find the tracks of one vehicle across every observer of a sightings database "
             "(appearance + road-network gate) and write its sightings",
        description=(
            "Re-identify a vehicle the way the experiments do (the paper's calc_traj and "
            "dashtraj's additions): the query is the first crop within --max-distance of the "
            "track you point at (--track OBSERVER:TRACK; dashtraj reid query helps find it), "
            "the gallery every crop of every observer; each track is the vehicle when its "
            "aggregated embedding distance is within the ReID model's calibrated threshold, "
            "then the spatio-temporal gate on the road network drops tracks the vehicle could "
            "not have reached. Writes the accepted tracks' sightings (one per track every "
            "--sample seconds) as the CSV that dashtraj reconstruct takes. Works on a "
            "database without ground truth (a drive, CARLA's or your own); where the truth "
            "is known, --json also scores the decision. Crops without a vector of the model "
            "are embedded and the vectors stored in DB first (as dashtraj reid embed)."
        ),
    )
    p.add_argument("db", metavar="DB", help="sightings database (perceive; file or URL)")
    p.add_argument("--track", type=_track, required=True, metavar="OBS:TRACK",
                   help="the query: a track of the vehicle to follow")
    p.add_argument("--map", required=True, metavar="MAP",
                   help="the run's road map (.xodr or a built-in town): the gate routes on it")
    p.add_argument("--model", default=None, metavar="M.onnx",
                   help="ReID model with its calibrated M.threshold.json (default: shipped)")
    p.add_argument("--threshold-file", default=None, metavar="T.json",
                   help="the calibrated threshold (default: beside the model)")
    p.add_argument("--no-gate", action="store_true",
                   help="appearance only (the paper): no road-network gate")
    p.add_argument("--max-distance", type=positive_float, default=15.0, metavar="M",
                   help="ReID range: detections estimated this close, metres (default 15)")
    add_range_args(p, "--max-distance")
    add_watch_arg(p)
    add_lookalike_arg(p)
    p.add_argument("--sample", type=positive_float, default=0.5, metavar="S",
                   help="one sighting per track every S seconds (default 0.5)")
    p.add_argument("--vehicle", type=int, default=None, metavar="ID",
                   help="the vehicle's true id where the database has truth: score with it")
    p.add_argument("-o", "--output", required=True, metavar="CSV", help="sightings CSV")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_output_args(p)
    p.set_defaults(func=run_reidentify)


def run_reidentify(args: argparse.Namespace) -> int:
    from dashtraj.cli._args import load_map
    from dashtraj.cli._vision_args import route_range
    from dashtraj.errors import DashtrajError
    from dashtraj.outputs import atomic_output, check_output
    from dashtraj.reid.embed import ReidEmbedder, shipped_model_path
    from dashtraj.reidentify.vision import load_threshold, target_from_db
    from dashtraj.store import SightingsDB
    from dashtraj.store.backend import display_name
    from dashtraj.trajectory.io import write_sightings

    check_output(args.output, overwrite=args.overwrite, kind="file")
    road_map = load_map(args.map, "--map")
    model = args.model or shipped_model_path()
    th = load_threshold(model, args.threshold_file)
    with SightingsDB.open(args.db) as db:
        if not any((t.observer_id, t.track_id) == args.track for t in db.tracks()):
            raise DashtrajError(f"--track {args.track[0]}:{args.track[1]}: no such track in "
                                f"{display_name(args.db)}")
        if db.count("crops") == 0:
            raise DashtrajError(f"{display_name(args.db)} has no crops (perceive keeps crops of "
                                "detections within --reid-range)")
    tt = target_from_db(args.db, road_map, args.vehicle, query_track=args.track,
                        embedder=ReidEmbedder(model, threads=2),
                        threshold=th.calibration.threshold, recipe=th.calibration.recipe,
                        gate=not args.no_gate, max_distance_m=args.max_distance,
                        sample_s=args.sample, gallery_m=args.gallery_range,
                        route_m=route_range(args.route_range, args.gallery_range,
                                            args.max_distance),
                        **({} if args.watch is None else {"watch": args.watch}),
                        **({} if args.lookalike is None else {"lookalike": args.lookalike}))
    s = tt.summary
    if s["query"] is None:
        raise DashtrajError(f"--track {args.track[0]}:{args.track[1]} has no crop within "
                            f"{args.max_distance:g} m to query with")
    with atomic_output(args.output, overwrite=args.overwrite, kind="file") as tmp:
        write_sightings(tmp, tt.sightings)
    accepted = sorted(tt.true_match, key=lambda k: tuple(k))
    info = {"db": display_name(args.db), "output": str(args.output),
            "query_track": list(args.track), "accepted_tracks": [list(k) for k in accepted],
            "sightings": len(tt.sightings), **{k: v for k, v in s.items() if k != "query"},
            "query": s["query"]}
    if args.json:
        print(json.dumps(info))
    else:
        names = ", ".join(":".join(str(v) for v in k) for k in accepted) or "none"
        print(f"{args.output}: {len(tt.sightings)} sightings from {len(accepted)} tracks "
              f"({names}); {s['reid_candidates']} of {s['reid_tracks']} tracks within "
              f"{args.max_distance:g} m passed the threshold, the gate kept "
              f"{s['reid_candidates'] - s['reid_gated_out']}")
    return 0
