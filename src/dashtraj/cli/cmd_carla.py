"""`dashtraj carla-record -o DIR`: record a drive from a running CARLA server (the bridge:
`dashtraj.datasets.carla_bridge`)."""

from __future__ import annotations

import argparse
import json


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `carla-record` command."""
    from dashtraj.cli._args import count, duration, image_size, positive_float, positive_int, seed
    from dashtraj.outputs import add_output_args

    p = subparsers.add_parser(
        "carla-record",
        help="record a drive (dashcam images, camera poses, truth) from a running CARLA server",
        description=(
            "Connect to a running CARLA 0.9.x server (the carla client package), spawn "
            "observers with dashcams and agents (the first is the target) driven by its "
            "Traffic Manager, step it synchronously every --every seconds, and write a drive: "
            "DIR/<observer>/<frame>.jpg, poses.csv (each image's camera transform), "
            "drive.json, map.xodr (the server's map), truth.csv (every vehicle, evaluation "
            "only) and target_route.csv. Then: dashtraj perceive DIR --detector M.onnx. The "
            "server's settings are restored and the spawned actors destroyed, whatever "
            "happens."
        ),
    )
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="drive folder to write")
    p.add_argument("--host", default="localhost", help="CARLA server host (default localhost)")
    p.add_argument("--port", type=positive_int, default=2000, help="its port (default 2000)")
    p.add_argument("--timeout", type=positive_float, default=20.0, metavar="S",
                   help="seconds to wait for the server (default 20)")
    p.add_argument("--town", default=None,
                   help="load this map first (e.g. Town10HD_Opt; default: the server's world)")
    p.add_argument("--observers", type=positive_int, default=4, help="dashcam vehicles (4)")
    p.add_argument("--agents", type=positive_int, default=20,
                   help="other vehicles, the first being the target (default 20)")
    p.add_argument("--duration", type=duration, default=60.0, metavar="S",
                   help="seconds of simulation to record (default 60)")
    p.add_argument("--every", type=positive_float, default=0.1, metavar="S",
                   help="simulation step and frame period, seconds (default 0.1; CARLA's "
                        "physics wants at most 0.1)")
    p.add_argument("--size", type=image_size, default="1280x720", metavar="WxH",
                   help="image size (default 1280x720, the paper's)")
    p.add_argument("--fov", type=positive_float, default=90.0, metavar="DEG",
                   help="horizontal field of view (default 90)")
    p.add_argument("--seed", type=seed, default=0, help="spawn and Traffic Manager seed")
    p.add_argument("--tm-port", type=count, default=8000, help="Traffic Manager port (8000)")
    p.add_argument("--no-depth", action="store_true",
                   help="no depth camera (by default each dashcam has one, saved as "
                        "<frame>.depth.png: the truth boxes then hug the vehicles' pixels)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_output_args(p)
    p.set_defaults(func=run_carla_record)


def run_carla_record(args: argparse.Namespace) -> int:
    from dashtraj.cli._args import ArgumentError, progress_bar
    from dashtraj.datasets.carla_bridge import CarlaDriveConfig, connect, record_drive
    from dashtraj.datasets.frames import parse_size
    from dashtraj.outputs import atomic_output, check_output
    from dashtraj.world.camera import CameraSpec
    from dashtraj.world.recording import check_camera

    if args.every > 0.1 + 1e-9:
        raise ArgumentError(f"--every {args.every:g}: CARLA's physics needs a step of at most "
                            "0.1 s")
    w, h = parse_size(args.size)
    cam = CameraSpec(width_px=w, height_px=h, fov_deg=float(args.fov))
    check_camera(cam, "--size/--fov", ArgumentError)
    out = check_output(args.output, overwrite=args.overwrite, kind="dir")
    client = connect(args.host, args.port, args.timeout)
    cfg = CarlaDriveConfig(town=args.town, observers=args.observers, agents=args.agents,
                           duration_s=args.duration, every_s=args.every, camera=cam,
                           seed=args.seed, tm_port=args.tm_port, depth=not args.no_depth)
    n = int(args.duration / args.every + 1e-9) + 1
    with progress_bar(args.quiet, total=n, unit="step") as bar, \
            atomic_output(out, overwrite=args.overwrite, kind="dir") as tmp:
        s = record_drive(client, tmp, cfg, progress=bar)
    info = {"output": str(out), "town": s.town, "observers": s.observers, "target": s.target,
            "frames": s.frames}
    if args.json:
        print(json.dumps(info))
    else:
        print(f"{out}: {s.frames} steps of {len(s.observers)} dashcams on {s.town} (target "
              f"{s.target}); next: dashtraj perceive {out} --detector M.onnx")
    return 0
