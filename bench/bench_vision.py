"""Benchmark of the from-pixels perception of `dashtraj demo` / `experiments`: CPU seconds
and wall seconds of `perceive` with the shipped detector, the vision defaults against the
previous settings, measured in the same run on the same recording.

- previous: 10 frames/s, one process, the detector's two onnxruntime threads,
  class-aware NMS only;
- now: 5 frames/s (``--every 0.2``), observers in 2 worker processes with one
  onnxruntime thread each, class-agnostic NMS (`dashtraj.perception.detections.AGNOSTIC_NMS_IOU`).

CPU seconds (this process and its finished workers) measure the work on a shared
machine; the wall clock measures the load. The recording: town01, seed 0, 3 observers,
10 agents, ``--duration`` seconds; 640 x 360 frames in the look of the ReID threshold.

Usage:
    .venv/bin/python bench/bench_vision.py [--duration 20] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path


def timed(rec, db: Path, config, workers: int) -> dict:
    from dashtraj.experiments import Stages
    from dashtraj.perception.pipeline import perceive

    c0, t0 = Stages.cpu_s(), time.perf_counter()
    s = perceive(rec, db, config, workers=workers)
    cpu, wall = Stages.cpu_s() - c0, time.perf_counter() - t0
    return {"frames": s.frames, "detections": s.detections, "tracks": s.tracks,
            "crops": s.crops, "cpu_s": cpu, "wall_s": wall,
            "cpu_ms_per_frame": 1000 * cpu / max(s.frames, 1)}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    from dashtraj.experiments import ExperimentConfig, look_of, reid_model_of
    from dashtraj.perception.detect import default_model_path
    from dashtraj.perception.pipeline import PerceiveConfig
    from dashtraj.world.recording import Recording, RunConfig, simulate

    _, th = reid_model_of(ExperimentConfig(sightings="vision", reid="appearance"))
    look = look_of(ExperimentConfig(), th)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        simulate(RunConfig(map="town01", seed=0, duration_s=args.duration, n_observers=3,
                           n_agents=10), root / "rec")
        rec = Recording.open(root / "rec")
        base = dict(detector=str(default_model_path()), size=(640, 360), look=look)
        out = {
            # the earlier settings: class-aware NMS only (agnostic is PerceiveConfig's default)
            "previous": timed(rec, root / "a.db", PerceiveConfig(
                **base, every_s=0.1, agnostic_nms_iou=None), 1),
            "now": timed(rec, root / "b.db", PerceiveConfig(**base, every_s=0.2), 2),
        }
    for k, v in out.items():
        print(f"{k:9s} {v['frames']:5d} frames  {v['detections']:6d} detections  "
              f"{v['cpu_s']:7.1f} CPU-s ({v['cpu_ms_per_frame']:5.1f} ms/frame)  "
              f"{v['wall_s']:7.1f} s wall")
    ratio = out["previous"]["cpu_s"] / max(out["now"]["cpu_s"], 1e-9)
    print(f"now / previous: {ratio:.2f}x less CPU for the same recording")
    if args.json:
        Path(args.json).write_text(json.dumps({**out, "cpu_ratio": ratio}, indent=2) + "\n")


if __name__ == "__main__":
    main()
