"""`dashtraj tracker eval`: HOTA, IDF1, MOTA of the trackers on a recording's frames."""

from __future__ import annotations

import argparse
import json


def register(subparsers: argparse._SubParsersAction) -> None:
    from dashtraj.cli._args import add_frame_source_args, add_pose_noise_args

    p = subparsers.add_parser(
        "tracker", help="evaluate the trackers (HOTA, IDF1, MOTA) against the renderer's truth")
    sub = p.add_subparsers(dest="tracker_command", metavar="SUBCOMMAND")
    sub.required = True
    e = sub.add_parser(
        "eval", help="score sort, ego and the BoxMOT peers on the same detections",
        description=(
            "Render every observer's frames of each recording, detect (oracle: the renderer's "
            "exact boxes, or an ONNX model), run every tracker on the same detections and "
            "score them against the renderer's identities with HOTA, IDF1 and MOTA "
            "(TrackEval's definitions). BoxMOT's ByteTrack, OC-SORT and BoT-SORT (ECC) run "
            "as peers when the boxmot package can be imported (pip install '.[bench]'). "
            "ego is also scored offline: +backfill (a confirmed track's first boxes get its "
            "id), +relink (tracks cut where their look changes and the tracks of one "
            "vehicle that a gap split joined, by their ReID embeddings), "
            "+backfill+relink (both); and online: +live-relink (the same cut and join done "
            "frame by frame, as a live camera must report its ids)."),
    )
    add_frame_source_args(e, every_s=0.1)
    add_pose_noise_args(e)
    e.add_argument("--trackers", nargs="+", default=["sort", "ego"], metavar="NAME",
                   help="our trackers (default: sort ego)")
    e.add_argument("--peers", nargs="*", default=None, metavar="NAME",
                   help="BoxMOT peers (default: bytetrack ocsort botsort when boxmot imports; "
                        "give none to skip)")
    e.add_argument("--relink", action=argparse.BooleanOptionalAction, default=True,
                   help="also score ego+relink, ego+backfill+relink and ego+live-relink: "
                        "ego's output with "
                        "its tracks cut where their look changes (--relink-cut) and the "
                        "tracks of one vehicle that a gap split joined, by appearance (every "
                        "box >= 10 px high at 720 rows embedded by the ReID model; default on)")
    e.add_argument("--reid-model", default=None, metavar="M.onnx",
                   help="--relink's ReID model: the live re-linking's, and the offline one's "
                        "unless --relink-model is given (default: the shipped model)")
    e.add_argument("--relink-model", default=None, metavar="M.onnx",
                   help="the offline re-linking's (+relink, +backfill+relink) ReID model "
                        "(default: the shipped track-join model, efficientnet_lite0_join.onnx; "
                        "--reid-model's when only that is given)")
    e.add_argument("--relink-cut", type=_cut_distance, default=None, metavar="D|none",
                   help="--relink cuts a track where the mean looks of its two parts are more "
                        "than D apart (default: Relink's, 0.8; none: never cut, only join)")
    e.add_argument("--json", action="store_true", help="print the result as JSON")
    e.set_defaults(func=run_eval)


def _cut_distance(text: str) -> float | str:
    """``--relink-cut``: a number > 0, or ``"none"``."""
    from dashtraj.cli._args import positive_float

    return "none" if text.strip().lower() == "none" else positive_float(text)


def run_eval(args: argparse.Namespace) -> int:
    from dashtraj.cli._args import detector_filters_used
    from dashtraj.perception.evaluate import open_recording, tracker_eval
    from dashtraj.perception.peers import PEER_NAMES, boxmot_peers
    from dashtraj.perception.track import build_tracker

    for n in args.trackers:
        build_tracker(n)
    size = None
    if args.size:
        from dashtraj.datasets.frames import parse_size

        size = parse_size(args.size)
    wanted = list(PEER_NAMES) if args.peers is None else list(args.peers)
    unknown = [n for n in wanted if n not in PEER_NAMES]
    if unknown:
        from dashtraj.cli._args import ArgumentError

        raise ArgumentError(f"--peers {unknown[0]!r} is not a BoxMOT peer; valid: "
                            f"{', '.join(PEER_NAMES)}")
    recs = [open_recording(r) for r in args.recordings]
    embedder = relink_embedder = None
    settings = ({} if args.relink_cut is None else
                {"split_distance": None if args.relink_cut == "none" else args.relink_cut})
    if args.relink:
        from dashtraj.cli._args import require_file
        from dashtraj.reid.embed import ReidEmbedder, join_model_path

        require_file("--reid-model", args.reid_model)
        require_file("--relink-model", args.relink_model)
        embedder = ReidEmbedder(args.reid_model)
        off = args.relink_model or args.reid_model or join_model_path()
        relink_embedder = None if off == args.reid_model else ReidEmbedder(off)
    peers, why = boxmot_peers(wanted) if wanted else ({}, None)
    res = tracker_eval(recs, args.trackers, peers, args.detector, args.every, size,
                       args.agnostic_nms, args.min_score, args.confirm_score,
                       pose_noise=args.pose_noise, pose_noise_seed=args.pose_noise_seed,
                       calibrate_pitch=args.calibrate_pitch, embedder=embedder,
                       relink_settings=settings, relink_embedder=relink_embedder)
    res["pose_noise"] = None if args.pose_noise is None else list(args.pose_noise)
    res["calibrate_pitch"] = args.calibrate_pitch
    res["detector"] = args.detector
    res["reid_model"] = None if embedder is None else str(embedder.path)
    res["relink_model"] = None if embedder is None else str((relink_embedder or embedder).path)
    if embedder is not None:
        from dashtraj.perception.track import Relink

        res["relink_cut"] = Relink(**settings).split_distance
    res.update(detector_filters_used(args))
    res["peers_skipped"] = None if peers or not wanted else why
    if args.json:
        print(json.dumps(res))
        return 0
    print(f"{len(recs)} recordings, {res['sequences']} observer videos, {res['frames']} frames, "
          f"detector {args.detector}")
    offline = [f"{n}+{k}" for n in args.trackers
               for k in ("backfill", "relink", "backfill+relink", "live-relink")
               if f"{n}+{k}" in res]
    for n in [*args.trackers, *offline, *peers]:
        r = res[n]
        ig = r["ignore_regions"]
        print(f"  {n:21s} HOTA {r['hota']:.3f}  IDF1 {r['idf1']:.3f}  MOTA {r['mota']:.3f}  "
              f"IDSW {r['idsw']:4d}  {r['updates_per_s'] or 0:,.0f} updates/s  "
              f"(ignore regions: HOTA {ig['hota']:.3f}  IDF1 {ig['idf1']:.3f}  "
              f"MOTA {ig['mota']:.3f})")
    if res["peers_skipped"]:
        print(f"  BoxMOT peers skipped: {res['peers_skipped']}")
    return 0
