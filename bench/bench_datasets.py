"""Benchmark of dashtraj.datasets: ReID images/s (1 and 2 workers) and detection frames/s.

ReID: ``--ids`` identities × ``--cameras`` ring cameras at ``--size`` (crops written as
JPEG, everything included except the one-off worker start-up, which is timed apart),
and the projected wall time of the paper-sized set (700 × 85; target ≤ 15 min on two
cores). Detection: frames/s of ``build_detection_dataset`` at 640×360 on a short
town10 recording (rendering, labels, JPEG and label files).

Usage:
    .venv/bin/python bench/bench_datasets.py [--ids 20] [--cameras 85] [--size 256]
        [--workers 1 2] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path


def bench_reid(ids: int, cameras: int, size: int, workers: int, root: Path) -> dict:
    from dashtraj.datasets.reid import ReidConfig, build_reid_dataset

    # warm-up run (1 id) measures the start-up: map, scene meshes, GL contexts, spawn
    cfg0 = ReidConfig(n_ids=2, n_cameras=1, size=size, n_test_ids=1)
    t0 = time.perf_counter()
    build_reid_dataset(cfg0, root / f"warm{workers}", workers=workers)
    startup = time.perf_counter() - t0
    cfg = ReidConfig(n_ids=ids, n_cameras=cameras, size=size)
    t0 = time.perf_counter()
    info = build_reid_dataset(cfg, root / f"reid{workers}", workers=workers)
    wall = time.perf_counter() - t0
    n = sum(c["images"] for c in info["counts"].values())
    rate = n / max(wall - startup, 1e-9)
    return {"workers": workers, "images": n, "wall_s": round(wall, 2),
            "startup_s": round(startup, 2), "images_per_s": round(rate, 1),
            "projected_700x85_min": round((700 * cameras / rate + startup) / 60, 1)}


def bench_detection(root: Path, duration_s: float = 10.0) -> dict:
    from dashtraj.datasets.detection import DetectionConfig, build_detection_dataset
    from dashtraj.world.recording import Recording, RunConfig, simulate

    simulate(RunConfig(map="town10", seed=0, duration_s=duration_s, n_observers=4,
                       n_agents=20), root / "rec")
    rec = Recording.open(root / "rec")
    cfg = DetectionConfig(every_s=0.5, size=(640, 360))
    t0 = time.perf_counter()
    info = build_detection_dataset([rec], root / "det", cfg)
    wall = time.perf_counter() - t0
    frames = sum(c["images"] for c in info["counts"].values())
    boxes = sum(c["labels"] for c in info["counts"].values())
    return {"frames": frames, "boxes": boxes, "wall_s": round(wall, 2),
            "frames_per_s": round(frames / wall, 1)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ids", type=int, default=20)
    ap.add_argument("--cameras", type=int, default=85)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--json", type=Path, help="write the results here")
    args = ap.parse_args(argv)
    from dashtraj.render.gl import context_info, create_context

    ctx = None
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        results = {"reid": [], "detection": None}
        for w in args.workers:
            r = bench_reid(args.ids, args.cameras, args.size, w, root)
            results["reid"].append(r)
            print(f"reid {args.ids} ids x {args.cameras} cameras at {args.size}, {w} worker(s): "
                  f"{r['images']} images, {r['images_per_s']} images/s (start-up "
                  f"{r['startup_s']} s); projected 700 x {args.cameras}: "
                  f"{r['projected_700x85_min']} min")
        d = bench_detection(root)
        results["detection"] = d
        print(f"detection 640x360: {d['frames']} frames, {d['boxes']} boxes, "
              f"{d['frames_per_s']} frames/s")
        ctx = create_context(threads=0)
        results["gl"] = context_info(ctx)
        ctx.release()
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
