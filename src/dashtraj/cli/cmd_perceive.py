"""`dashtraj perceive`: a recording → the sightings database (render, detect, track,
localize, map-match every observer's frames)."""

from __future__ import annotations

import argparse
import json


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `perceive` command."""
    from dashtraj.cli._args import (
        add_detector_filter_args,
        add_pose_noise_args,
        image_size,
        int_at_least,
        positive_float,
        positive_int,
    )
    from dashtraj.cli.cmd_detect import add_classifier_arg
    from dashtraj.outputs import add_output_args

    p = subparsers.add_parser(
        "perceive",
        help="render, detect, track, localize and map-match every observer's frames into a "
             "sightings database",
        description=(
            "Per observer of a recording: render its dashcam frames on the fly (or, for a "
            "drive, read its images), detect the "
            "vehicles (the renderer's exact boxes with --detector oracle, or an ONNX model), "
            "track them (sort, or ego: ground-plane tracking with the observer's odometry), "
            "localize them (paper: Eq. 3; ground: bottom edge on the road; fused; tracked: "
            "fused, or the track's ground-plane filter for truncated or occluded boxes; smoothed: "
            "the same filter forward and backward in time, positions rewritten when the "
            "observer's frames end; mapped: smoothed, and a position beside every lane moved "
            "along its ray onto the nearest one), map-match "
            "them to waypoints, and write the sightings database (an SQLite file, or a schema of "
            "a PostgreSQL database where --workers write in parallel; with the crops of "
            "the detections within the ReID range)."
        ),
    )
    p.add_argument("recording", metavar="RUN",
                   help="recording directory (dashtraj simulate), or a drive: a folder of "
                        "dashcam images with their camera poses (drive.json, poses.csv; "
                        "dashtraj render writes one; see dashtraj.datasets.drive)")
    p.add_argument("-o", "--output", required=True, metavar="DB",
                   help="database file to write (SQLite), or a PostgreSQL URL "
                        "postgresql://[user@]host[:port]/dbname[?schema=NAME] (one schema per "
                        "run, default dashtraj; needs pip install 'dashtraj[postgres]')")
    p.add_argument("--append", action="store_true",
                   help="add these observers to the run at DB (perceived from the same "
                        "recording or drive, with the same settings and detector; several "
                        "machines may each append their own observers; default "
                        "--observers: those the run lacks); the run is created when there is "
                        "none yet")
    p.add_argument("--detector", default="oracle", metavar="oracle|M.onnx",
                   help="detector (default oracle: the renderer's exact visible boxes, or a "
                        "drive's truth boxes from its truth.csv)")
    add_classifier_arg(p)
    add_detector_filter_args(p)
    add_pose_noise_args(p)
    p.add_argument("--tracker", default="ego", help="sort or ego (default ego)")
    p.add_argument("--live-relink", action="store_true",
                   help="re-link ego's tracks by appearance as the frames come: the tracks "
                        "of one vehicle that a gap split share one id, a track that went on "
                        "with another vehicle's boxes is cut (every box >= 10 px high at 720 "
                        "rows embedded by the ReID model; dashtraj tracker eval scores it as "
                        "ego+live-relink)")
    p.add_argument("--reid-model", default=None, metavar="M.onnx",
                   help="--live-relink's ReID model (default: the shipped one)")
    p.add_argument("--localizer", default="smoothed",
                   help="paper, ground, fused, tracked, smoothed or mapped (default smoothed)")
    p.add_argument("--mu-h", type=positive_float, metavar="PX",
                   help="Eq. 3's calibrated sensor constant (dashtraj localization calibrate)")
    p.add_argument("--every", type=positive_float, default=0.1, metavar="S",
                   help="frame period, seconds (default 0.1 = 10 fps)")
    p.add_argument("--size", type=image_size, metavar="WxH",
                   help="image size (default: the recording's camera)")
    p.add_argument("--msaa", type=int_at_least(0), default=0,
                   help="renderer colour samples (default 0)")
    p.add_argument("--observers", type=int_at_least(0), nargs="+", metavar="ID",
                   help="observer vehicle ids (default all)")
    p.add_argument("--reid-range", type=positive_float, default=15.0, metavar="M",
                   help="keep image crops of detections this close, metres (default 15)")
    p.add_argument("--look", default=None, metavar="PRESET",
                   help="render look preset (dashtraj.render.look; default: the renderer's)")
    p.add_argument("--workers", type=positive_int, default=1, metavar="N",
                   help="observers processed in parallel processes (default 1)")
    p.add_argument("--parallel-frames", type=int_at_least(0), default=None, metavar="N",
                   help="frames detected at once in threads while a thread renders ahead "
                        "(default 2 in one process, 1 per worker; 0: all in turn on one "
                        "thread); the database does not depend on it")
    p.add_argument("--threads", type=positive_int, default=None, metavar="N",
                   help="onnxruntime threads of each detector model run (default 1)")
    p.add_argument("--save-frames", metavar="DIR",
                   help="also write the rendered frames as DIR/<observer>/<frame>.jpg")
    p.add_argument("--mot", metavar="DIR",
                   help="also write the tracks as MOTChallenge txt, DIR/<observer>.txt")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_output_args(p)
    p.set_defaults(func=run_perceive)


def run_perceive(args: argparse.Namespace) -> int:
    import contextlib
    import dataclasses
    import time

    from dashtraj.cli._args import progress_bar
    from dashtraj.cli.cmd_detect import classifier_path_from_arg
    from dashtraj.errors import DashtrajError
    from dashtraj.outputs import atomic_output, check_output
    from dashtraj.perception.pipeline import (
        PerceiveConfig,
        check_drive_config,
        check_relink_config,
        open_source,
        perceive,
        write_mot,
    )

    if args.workers < 1:
        raise DashtrajError(f"--workers must be >= 1, got {args.workers}")
    size = None
    if args.size:
        from dashtraj.datasets.frames import parse_size

        size = parse_size(args.size)
    if args.msaa > 1:  # before the database is created (the workers render later)
        from dashtraj.render.gl import check_samples, create_context

        ctx = create_context()
        try:
            check_samples(ctx, args.msaa, "--msaa")
        finally:
            ctx.release()
    from dashtraj.store.pg_output import check_db_output, db_output

    if args.append and args.overwrite:
        raise DashtrajError("--append adds observers to a run and --overwrite replaces it "
                            "whole; give one of them")
    check_db_output(args.output, overwrite=args.overwrite, append=args.append)
    for extra in (args.save_frames, args.mot):
        if extra:
            check_output(extra, overwrite=args.overwrite, kind="dir")
    rec = open_source(args.recording)
    cfg = PerceiveConfig(detector=args.detector, tracker=args.tracker, localizer=args.localizer,
                         mu_h=args.mu_h, every_s=args.every, size=size, msaa=args.msaa,
                         reid_range_m=args.reid_range, look=args.look,
                         agnostic_nms_iou=args.agnostic_nms, min_score=args.min_score,
                         classifier=classifier_path_from_arg(args.classifier),
                         confirm_score=args.confirm_score,
                         pose_noise=args.pose_noise, pose_noise_seed=args.pose_noise_seed,
                         calibrate_pitch=args.calibrate_pitch,
                         live_relink=args.live_relink, reid_model=args.reid_model,
                         threads=args.threads, parallel_frames=args.parallel_frames,
                         observers=tuple(args.observers) if args.observers else None)
    check_relink_config(cfg)
    from dashtraj.datasets.drive import Drive
    from dashtraj.datasets.frames import observer_ids, sample_steps

    obs = list(args.observers) if args.observers else observer_ids(rec)
    if args.append:
        obs = _observers_to_append(args, rec, cfg, obs)
        cfg = dataclasses.replace(cfg, observers=tuple(obs))
    if isinstance(rec, Drive):
        check_drive_config(cfg, rec)
        total = rec.frame_count(args.every, obs)
    else:
        total = len(obs) * len(sample_steps(rec, args.every))
    n_obs = len(obs)
    t0 = time.perf_counter()
    with contextlib.ExitStack() as stack:
        progress = stack.enter_context(progress_bar(args.quiet, total=total, unit="frame"))
        frames_tmp = (stack.enter_context(atomic_output(args.save_frames,
                                                        overwrite=args.overwrite))
                      if args.save_frames else None)
        tmp = stack.enter_context(db_output(args.output, overwrite=args.overwrite,
                                            keep_partial=True, append=args.append))
        summary = perceive(rec, tmp, cfg, workers=args.workers, progress=progress,
                           frames_dir=frames_tmp)
    wall = time.perf_counter() - t0
    if args.mot:
        with atomic_output(args.mot, overwrite=args.overwrite) as mot_tmp:
            write_mot(args.output, mot_tmp)
    from dashtraj.store.backend import display_name

    info = {"db": display_name(args.output), "observers": summary.observers,
            "frames": summary.frames, "detections": summary.detections,
            "tracks": summary.tracks, "crops": summary.crops,
            "detector": cfg.detector, "tracker": cfg.tracker, "localizer": cfg.localizer,
            "wall_s": round(wall, 3),
            "frames_per_s_per_observer": round(summary.frames / wall / min(args.workers, n_obs),
                                               2) if wall > 0 else None}
    if args.append:
        from dashtraj.store import SightingsDB

        with SightingsDB.open(args.output, check=False) as db:
            info["run_observers"] = [o["observer_id"] for o in db.observers()]
    if args.json:
        print(json.dumps(info))
    else:
        verb = "appended" if args.append else "wrote"
        print(f"{info['db']}: {verb} {summary.observers} observers, {summary.frames} frames, "
              f"{summary.detections} detections in {summary.tracks} tracks, {summary.crops} "
              f"crops ({cfg.detector} / {cfg.tracker} / {cfg.localizer}; {wall:.1f} s)"
              + (f"; the run has observers {', '.join(map(str, info['run_observers']))}"
                 if args.append else ""))
    return 0


def _observers_to_append(args: argparse.Namespace, rec, cfg, obs: list[int]) -> list[int]:
    """``--append``: refuse a run that is not this one (before any work), and the observers
    it has; without ``--observers``, the observers of the source that it lacks."""
    from dashtraj.errors import DashtrajError
    from dashtraj.perception.pipeline import perceive_identity
    from dashtraj.store.append import check_append
    from dashtraj.store.backend import display_name

    have = check_append(args.output, perceive_identity(rec, cfg)) or []
    where = display_name(args.output)
    if args.observers:
        both = sorted(set(obs) & set(have))
        if both:
            raise DashtrajError(f"--observers: {where} already has observer"
                                f"{'s' if len(both) > 1 else ''} {', '.join(map(str, both))}")
        return obs
    left = [o for o in obs if o not in have]
    if not left:
        raise DashtrajError(f"--append: {where} already has every observer of "
                            f"{args.recording} ({', '.join(map(str, have))})")
    return left
