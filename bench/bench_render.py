"""Benchmark of dashtraj.render: frames per second with 20 vehicles in view.

Labels included (instance, depth and silhouette passes), image encoding excluded.
Scene: the synthetic straight town of the render tests (`dashtraj.render.synthetic`),
camera on a lane looking down the road at 20 vehicles (dense: most overlap in the image, 11 hidden).

Usage:
    .venv/bin/python bench/bench_render.py [--frames 60] [--threads 0] [--msaa 4 0]

``--threads 0`` makes llvmpipe rasterize on the calling thread (one core); the
targets are ≥ 100 fps at 640×360 and ≥ 25 fps at 1280×720 on one core. The
one-core figure is the CPU time per frame (``time.process_time``, all threads): on
a machine whose cores are shared, wall-clock time also counts waiting for a core.
Each ``--msaa`` value is timed (0: one pass for colour, ids and depth, no AA; 4:
MSAA colour pass + id/depth pass; llvmpipe supports only 4 samples).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np


def scene_vehicles(n: int, rng: np.random.Generator):
    """``n`` vehicles on the straight town's four lanes, 8–90 m ahead of a camera at x=-95."""
    from dashtraj.render.synthetic import BIKE, BUS, MOTO, SEDAN, SUV, TRUCK, VAN, identity

    models = [SEDAN, SEDAN, SUV, SUV, VAN, TRUCK, BUS, MOTO, BIKE, SEDAN]
    lanes = [(-5.25, 180.0), (-1.75, 180.0), (1.75, 0.0), (5.25, 0.0)]
    out = []
    for i in range(n):
        y, yaw = lanes[i % 4]
        x = -87.0 + 82.0 * (i // 4) / max(1, (n - 1) // 4) + rng.uniform(-2, 2)
        rgb = tuple(int(c) for c in rng.integers(20, 235, 3))
        out.append(
            (
                i + 1,
                identity(models[i % len(models)], rgb, i + 1),
                x,
                y,
                0.0,
                yaw + rng.uniform(-8, 8),
            )
        )
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--vehicles", type=int, default=20)
    ap.add_argument("--threads", type=int, default=0, help="llvmpipe threads (0 = one core)")
    ap.add_argument("--msaa", type=int, nargs="+", default=[4, 0])
    ap.add_argument("--no-depth", action="store_true", help="render(..., depth=False)")
    ap.add_argument("--json", type=Path, help="write the results here")
    args = ap.parse_args(argv)
    os.environ["LP_NUM_THREADS"] = str(args.threads)

    from dashtraj.render.gl import context_info, create_context
    from dashtraj.render.scene import Renderer
    from dashtraj.render.synthetic import STRAIGHT_XODR
    from dashtraj.roads import RoadMap

    ctx = create_context(args.threads)
    m = RoadMap.from_string(STRAIGHT_XODR, name="straight")
    vehicles = scene_vehicles(args.vehicles, np.random.default_rng(0))
    results = {
        "gl": context_info(ctx),
        "threads": args.threads,
        "vehicles": args.vehicles,
        "depth": not args.no_depth,
        "runs": [],
    }
    for msaa in args.msaa:
        for w, h in ((640, 360), (1280, 720)):
            r = Renderer(m, w, h, 90.0, msaa=msaa, ctx=ctx)
            f = r.render((-95.0, 1.75, 1.6, 0.0, 0.0, 0.0), vehicles)  # warm up
            n_view = sum(lb.in_view for lb in f.labels)
            times, cpu = [], []
            for i in range(args.frames):
                pose = (-95.0 + 0.05 * i, 1.75, 1.6, 0.0, 0.0, 0.0)
                t, c = time.perf_counter(), time.process_time()
                r.render(pose, vehicles, depth=not args.no_depth)
                times.append(time.perf_counter() - t)
                cpu.append(time.process_time() - c)
            r.release()
            t_med, c_med = float(np.median(times)), float(np.median(cpu))
            run = {
                "size": f"{w}x{h}",
                "msaa": msaa,
                "fps_cpu": 1.0 / c_med,
                "cpu_ms_median": 1e3 * c_med,
                "fps_wall": 1.0 / t_med,
                "ms_median": 1e3 * t_med,
                "ms_p90": 1e3 * float(np.percentile(times, 90)),
                "vehicles_in_view": n_view,
            }
            results["runs"].append(run)
            # with --threads 0 all rasterization runs on this thread, so CPU time per
            # frame is the one-core cost even while other processes share the machine
            print(
                f"{w}x{h} msaa {msaa}: CPU {1e3 * c_med:6.2f} ms/frame = {1.0 / c_med:6.1f} fps "
                f"(one core); wall {1.0 / t_med:6.1f} fps (median {1e3 * t_med:.2f} ms, "
                f"p90 {run['ms_p90']:.2f} ms); {n_view}/{args.vehicles} vehicles visible, "
                f"llvmpipe threads {args.threads}"
            )
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
